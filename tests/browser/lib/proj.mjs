// Geoid undulations from PROJ's command-line tools (proj-bin), never from our server.
import { execFileSync } from 'node:child_process';

// Debian's proj-data: EGM96 on a 15′ grid (NOAA GTX).
export const EGM96_GRID = process.env.TESSERA_GEOID ?? '/usr/share/proj/egm96_15.gtx';

// N (metres, ellipsoid minus geoid) at each [lon, lat]: `cs2cs` from WGS84 with heights above
// the geoid (+geoidgrids) to EPSG:4979 (heights above the ellipsoid), of H = 0, so h = H + N = N.
// The source CRS is +proj=longlat, so input is "lon lat H"; EPSG:4979's axis order makes the
// output "lat lon h".
export function undulations(lonLats, grid = EGM96_GRID) {
  const input = lonLats.map(([lon, lat]) => `${lon} ${lat} 0`).join('\n') + '\n';
  const out = execFileSync('cs2cs', ['-f', '%.9f', `+proj=longlat +datum=WGS84 +geoidgrids=${grid} +type=crs`,
    '+to', 'EPSG:4979'], { input, encoding: 'utf8' });
  return out.trim().split('\n').map((line, k) => {
    const [lat, lon, h] = line.trim().split(/\s+/).map(Number);
    const [lon0, lat0] = lonLats[k];
    if (!(Math.abs(lat - lat0) < 1e-6 && Math.abs(lon - lon0) < 1e-6 && Number.isFinite(h))) {
      throw new Error(`cs2cs: unexpected output "${line}" for ${lon0} ${lat0}`);
    }
    return h;
  });
}
