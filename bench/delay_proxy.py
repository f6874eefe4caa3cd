#!/usr/bin/env python3
"""A TCP proxy that adds latency: every response from upstream is held for DELAY
milliseconds before its first byte is passed on (a pause of 20 ms in the upstream
stream starts a new response). Used by bench/stream.sh to fly through 150 ms of
added round-trip latency.

    delay_proxy.py LISTEN_PORT UPSTREAM_HOST:PORT DELAY_MS
Prints "listening on 127.0.0.1:PORT" once ready.
"""
import asyncio
import sys


async def pump_up(reader, writer):
    try:
        while data := await reader.read(65536):
            writer.write(data)
            await writer.drain()
    except (ConnectionError, asyncio.CancelledError):
        pass
    finally:
        writer.close()


async def pump_down(reader, writer, delay):
    fresh = True
    try:
        while True:
            try:
                data = await asyncio.wait_for(reader.read(65536), 0.02)
            except asyncio.TimeoutError:
                fresh = True
                continue
            if not data:
                break
            if fresh:
                await asyncio.sleep(delay)
                fresh = False
            writer.write(data)
            await writer.drain()
    except ConnectionError:
        pass
    finally:
        writer.close()


async def main():
    port, upstream, delay_ms = int(sys.argv[1]), sys.argv[2], float(sys.argv[3])
    host, uport = upstream.rsplit(":", 1)

    async def handle(cr, cw):
        try:
            sr, sw = await asyncio.open_connection(host, int(uport))
        except OSError:
            cw.close()
            return
        up = asyncio.create_task(pump_up(cr, sw))
        await pump_down(sr, cw, delay_ms / 1000.0)
        up.cancel()

    server = await asyncio.start_server(handle, "127.0.0.1", port)
    print(f"listening on 127.0.0.1:{server.sockets[0].getsockname()[1]}", flush=True)
    async with server:
        await server.serve_forever()


if __name__ == "__main__":
    asyncio.run(main())
