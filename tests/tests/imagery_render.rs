//! Imagery pyramids (DECISIONS.md "Imagery pyramids"), the renderer: the Olinda DEM drawn
//! straight down with its Landsat imagery (bands 3,2,1) draped, on lavapipe. The imagery
//! comes from a real server (in process, real sockets) through the client's fetch; the
//! heights from the pyramid file.
//!
//! The check is the coastline. The expected frame is computed independently of the
//! shader: for each pixel, the camera's own matrices give the ray under it, the ray
//! meets the ground (the DEM's heights), and the ground point is looked up in the
//! finest `.tessimg` records with the texel-centre convention of FORMAT.md
//! ("Imagery pyramids"), bilinearly. Both frames are split into sea and land by
//! Otsu's threshold on blue minus red: with the build's stretch the sea of bands
//! 3,2,1 is cyan, not dark — the land's dark vegetation is darker — while no land
//! cover is bluer than red (the rendered frame is lit and hazed, which moves its
//! threshold, not its order). Away from a 2-pixel
//! band around the expected coast, ≥ 95 % of the pixels must agree. 2 px: the ray
//! meets the DEM's bilinear surface where the renderer draws triangles, and the
//! shader samples the imagery at a parallax-free `uv` while the expected frame uses
//! the exact ground point — sub-pixel differences that only matter at the coast.
//! 95 %: JPEG noise and haze flip a few isolated pixels of mixed texels (surf,
//! beaches, river mouths). The same comparison against the expected frame shifted
//! by one tile, or transposed, must fall short of it (checked here), and so does
//! the frame drawn with the hypsometric tint (imagery missing). The frame drawn with
//! only the root's imagery (the finest tiles read their ancestor's, at their place
//! in it) must clear it too.

#![allow(clippy::unwrap_used)] // test code: a failed unwrap is a failed test

use glam::{DVec3, DVec4};
use tessera_client::camera::Camera;
use tessera_client::render::slots::OnGpu;
use tessera_client::render::{RenderOptions, Renderer};
use tessera_client::select::{SelectParams, Selector, World};
use tessera_client::stream::imagery_tiles::{self as imagery, Texels};
use tessera_client::stream::pool::TilePool;
use tessera_client::stream::{StreamConfig, Streamer, TileSource};
use tessera_shared::{FileSource, Pyramid, TileId};

#[allow(dead_code)] // each test binary uses some of the shared fixtures
mod streaming_support;
use streaming_support::{olinda_with_imagery, serve_olinda};

const W: u32 = 320;
const H: u32 = 320;

/// How much bluer than red a colour is, offset into 0..=255: the sea here is cyan
/// (B > R), the land — dark vegetation, grey town, tan soil — is not.
fn seaness(p: [f64; 3]) -> f64 {
    (p[2] - p[0] + 128.0).clamp(0.0, 255.0)
}

/// Otsu's threshold of `values` in 0..=255.
fn otsu(values: &[f64]) -> f64 {
    let mut hist = [0f64; 256];
    for v in values {
        hist[v.round().clamp(0.0, 255.0) as usize] += 1.0;
    }
    let total = values.len() as f64;
    let sum: f64 = hist.iter().enumerate().map(|(i, n)| i as f64 * n).sum();
    let (mut w0, mut sum0, mut best, mut at) = (0.0, 0.0, -1.0, 0.0);
    for (i, n) in hist.iter().enumerate() {
        w0 += n;
        sum0 += i as f64 * n;
        let w1 = total - w0;
        if w0 == 0.0 || w1 == 0.0 {
            continue;
        }
        let (m0, m1) = (sum0 / w0, (sum - sum0) / w1);
        let between = w0 * w1 * (m0 - m1) * (m0 - m1);
        if between > best {
            best = between;
            at = i as f64 + 0.5;
        }
    }
    at
}

fn seaness_of(rgba: &[u8]) -> Vec<f64> {
    rgba.chunks(4)
        .map(|p| seaness([f64::from(p[0]), f64::from(p[1]), f64::from(p[2])]))
        .collect()
}

/// Sea (true) or land per pixel, by Otsu's threshold on [`seaness`].
fn classify(lum: &[f64]) -> Vec<bool> {
    let t = otsu(lum);
    lum.iter().map(|&l| l > t).collect()
}

/// Of the pixels farther than 2 px from a change of class in `expected`, the
/// fraction whose class `got` agrees with.
fn agreement(got: &[bool], expected: &[bool]) -> (f64, usize) {
    let (w, h) = (W as i64, H as i64);
    let at = |x: i64, y: i64| expected[(y.clamp(0, h - 1) * w + x.clamp(0, w - 1)) as usize];
    let (mut agree, mut n) = (0usize, 0usize);
    for y in 0..h {
        for x in 0..w {
            let c = at(x, y);
            let near_coast = (-2..=2).any(|dy| (-2..=2).any(|dx| at(x + dx, y + dy) != c));
            if near_coast {
                continue;
            }
            n += 1;
            agree += usize::from(got[(y * w + x) as usize] == c);
        }
    }
    (agree as f64 / n.max(1) as f64, n)
}

/// The finest-level imagery at finest sample `(sx, sy)`, bilinear between texel
/// centres (FORMAT.md: texel `u` of tile `x` is centred at sample
/// `x·T + (u + ½)·T/side`), clamped to the tile.
fn imagery_at(
    finest: &std::collections::HashMap<TileId, Texels>,
    g: &tessera_shared::TileGeometry,
    sx: f64,
    sy: f64,
) -> Option<[f64; 3]> {
    let t = f64::from(g.tile_size());
    let level = g.finest();
    let n = level.tiles_per_side();
    let (tx, ty) = (
        ((sx / t).floor().max(0.0) as u32).min(n - 1),
        ((sy / t).floor().max(0.0) as u32).min(n - 1),
    );
    let tex = finest.get(&TileId::new(level, tx, ty)?)?;
    let side = f64::from(tex.side);
    let u = (sx - f64::from(tx) * t) * side / t - 0.5;
    let v = (sy - f64::from(ty) * t) * side / t - 0.5;
    let texel = |u: i64, v: i64| {
        let (u, v) = (
            u.clamp(0, i64::from(tex.side) - 1),
            v.clamp(0, i64::from(tex.side) - 1),
        );
        let i = ((v * i64::from(tex.side) + u) * 4) as usize;
        [0, 1, 2].map(|c| f64::from(tex.rgba[i + c]))
    };
    let (u0, v0) = (u.floor(), v.floor());
    let (fu, fv) = (u - u0, v - v0);
    let (u0, v0) = (u0 as i64, v0 as i64);
    let (a, b, c, d) = (
        texel(u0, v0),
        texel(u0 + 1, v0),
        texel(u0, v0 + 1),
        texel(u0 + 1, v0 + 1),
    );
    Some([0, 1, 2].map(|k| {
        (a[k] * (1.0 - fu) + b[k] * fu) * (1.0 - fv) + (c[k] * (1.0 - fu) + d[k] * fu) * fv
    }))
}

#[test]
fn olinda_from_above_has_the_imagerys_coastline() {
    let dir = tempfile::tempdir().unwrap();
    let Some(out) = olinda_with_imagery(dir.path()) else {
        return;
    };

    let rt = tokio::runtime::Runtime::new().unwrap();
    let (base, client, info) = serve_olinda(&rt, &out);
    let im = info
        .imagery
        .clone()
        .expect("the document names the imagery");
    let world = World::from_dataset(&info, None).unwrap();
    let g = world.geometry;

    // Heights from the file, every tile resident and on the GPU.
    let pyramid = Pyramid::open_file(&out).unwrap();
    let all: Vec<TileId> = g
        .levels()
        .flat_map(|l| g.present_tiles(l).collect::<Vec<_>>())
        .collect();
    let mut pool = TilePool::new(all.len() + 1);
    for &t in &all {
        let rec = pyramid.read_tile(t).unwrap().unwrap();
        pool.insert(t, rec.errors, rec.heights, rec.mask);
    }
    let mut r = Renderer::new(
        world,
        (info.min_height, info.max_height),
        RenderOptions {
            width: W,
            height: H,
            slots: all.len() as u32 + 1,
            ..RenderOptions::default()
        },
    )
    .unwrap();
    r.enable_imagery(im.texels).unwrap();
    for &t in &all {
        assert!(r.upload(&pool, t), "no slot for {t}");
    }

    // Straight down over the coast south-east of the middle (a hair off vertical:
    // the view's up is +y), north at the top, the frame within the DEM.
    let size = world.size_m();
    let camera = Camera {
        position: DVec3::new(0.8 * size.x, 0.3 * size.x, 0.7 * size.y),
        yaw: 0.0,
        pitch: -std::f64::consts::FRAC_PI_2 + 1e-4,
        fovy: 60f64.to_radians(),
        width: W,
        height: H,
        near: 10.0,
        far: 4.0 * size.x,
    };
    let mut selector = Selector::new(
        world,
        SelectParams {
            tau: 0.5,
            ..SelectParams::default()
        },
    );
    let sel = selector.select(
        &camera,
        &OnGpu {
            pool: &pool,
            slots: &r.slots,
        },
    );
    assert!(sel.wanted.is_empty(), "everything is on the GPU");
    assert!(
        sel.tiles.iter().any(|t| t.level() == g.finest()),
        "the view draws finest tiles: {:?}",
        sel.tiles
    );

    // The imagery of exactly the drawn tiles, as a flight gets it: the streamer's
    // feed (opened on the server, as `tessera fly` opens it), settled, then
    // uploaded into the tiles' slots.
    assert_eq!(r.imagery_missing(&sel.tiles), sel.tiles);
    let frame_without = {
        r.draw(&camera, &sel.patches).unwrap();
        r.read_rgba().unwrap()
    };
    // Before the drawn tiles' own imagery arrives: their nearest ancestor's, the
    // root's, read at each tile's place in it.
    let root = TileId::new(tessera_shared::Level::new(0).unwrap(), 0, 0).unwrap();
    assert!(sel.tiles.iter().all(|t| t.level() > root.level()));
    let root_texels = rt
        .block_on(imagery::fetch(
            &client,
            &base,
            &im,
            root.level(),
            &imagery::ranges_by_level(&[root])[&root.level()],
        ))
        .unwrap();
    assert!(r.upload_imagery(root, &root_texels[0].1));
    r.resolve_imagery(&sel.tiles);
    let frame_ancestor = {
        r.draw(&camera, &sel.patches).unwrap();
        r.read_rgba().unwrap()
    };
    let (streamer, _) = Streamer::open(
        &TileSource::server(base.clone(), "olinda"),
        StreamConfig::default(),
        Some(rt.handle().clone()),
    )
    .unwrap();
    // `--no-imagery`: a renderer that is not to drape gets no feed.
    let mut tinted = Renderer::new(
        world,
        (info.min_height, info.max_height),
        RenderOptions {
            width: 8,
            height: 8,
            slots: 4,
            imagery: false,
            ..RenderOptions::default()
        },
    )
    .unwrap();
    assert!(
        tessera_client::app::headless::imagery_feed(&mut tinted, &streamer)
            .unwrap()
            .is_none()
    );
    let mut feed = streamer.imagery_feed(16).expect("the dataset has imagery");
    assert_eq!(feed.texels(), im.texels);
    assert!(feed.settle(&sel.tiles, std::time::Duration::from_secs(60)));
    assert!(feed.last_error.is_none(), "{:?}", feed.last_error);
    assert_eq!(
        r.upload_imagery_from(feed.pool(), &sel.tiles) as usize,
        sel.tiles.len()
    );
    // One request per level drawn (texture LOD follows geometry LOD), and no more
    // once every drawn tile has its imagery.
    let levels: std::collections::HashSet<_> = sel.tiles.iter().map(|t| t.level()).collect();
    assert_eq!(feed.requests as usize, levels.len());
    assert_eq!(feed.frame(&sel.tiles), 0);
    assert!(r.imagery_missing(&sel.tiles).is_empty());
    r.draw(&camera, &sel.patches).unwrap();
    let frame = r.read_rgba().unwrap();
    if let Ok(dir) = std::env::var("TESSERA_IMAGERY_PNG") {
        let dir = std::path::Path::new(&dir);
        tessera_client::render::png_out::write_png(&dir.join("olinda.png"), &frame, W, H).unwrap();
        tessera_client::render::png_out::write_png(
            &dir.join("olinda_tint.png"),
            &frame_without,
            W,
            H,
        )
        .unwrap();
    }

    // The expected frame, independently: pixel → ray → ground → finest record.
    let file =
        Pyramid::open_imagery(FileSource::open(&out.with_extension("tessimg")).unwrap()).unwrap();
    let finest: std::collections::HashMap<TileId, Texels> = g
        .present_tiles(g.finest())
        .map(|t| {
            let rec = file.read_record(t).unwrap().unwrap();
            (t, imagery::decode(&rec, im.texels).unwrap())
        })
        .collect();
    let inverse = camera.view_projection().inverse();
    let unproject = |x: f64, y: f64, z: f64| {
        let p = inverse * DVec4::new(x, y, z, 1.0);
        p.truncate() / p.w
    };
    let expected_at = |shift: (f64, f64), transpose: bool| -> Vec<f64> {
        let mut lum = Vec::with_capacity((W * H) as usize);
        for py in 0..H {
            for px in 0..W {
                let ndc_x = (f64::from(px) + 0.5) / f64::from(W) * 2.0 - 1.0;
                let ndc_y = 1.0 - (f64::from(py) + 0.5) / f64::from(H) * 2.0;
                let (a, b) = (unproject(ndc_x, ndc_y, 0.0), unproject(ndc_x, ndc_y, 1.0));
                let dir = b - a;
                // Meet the ground: the plane at the ground height under the last
                // estimate, twice (relief ≤ 90 m under a ~6 km eye).
                let mut h = 0.0;
                let mut p = a;
                for _ in 0..3 {
                    p = a + dir * ((h - a.y) / dir.y);
                    h = pool.ground_height(&world, p.x, p.z).unwrap_or(0.0);
                }
                let (mut sx, mut sy) = (p.x / world.spacing.x, p.z / world.spacing.y);
                if transpose {
                    (sx, sy) = (sy, sx);
                }
                let rgb = imagery_at(&finest, &g, sx + shift.0, sy + shift.1).unwrap_or([0.0; 3]);
                lum.push(seaness(rgb));
            }
        }
        lum
    };
    let rendered: Vec<f64> = frame
        .chunks(4)
        .map(|p| seaness([f64::from(p[0]), f64::from(p[1]), f64::from(p[2])]))
        .collect();
    let got = classify(&rendered);
    let expected = classify(&expected_at((0.0, 0.0), false));
    let sea = expected.iter().filter(|&&s| s).count() as f64 / expected.len() as f64;
    assert!(
        (0.1..0.9).contains(&sea),
        "the view holds both sea and land (sea {:.0} %)",
        sea * 100.0
    );
    let (ok, counted) = agreement(&got, &expected);
    eprintln!(
        "imagery coastline: {:.2} % of {counted} pixels agree; sea {:.0} % of the view",
        ok * 100.0,
        sea * 100.0
    );
    assert!(
        ok >= 0.95,
        "only {:.2} % of the pixels away from the coast agree on land and sea",
        ok * 100.0
    );
    // Wrong drapes the same comparison rejects: a tile west (the view is east of
    // the middle, so the shifted one is still inside the image), a tile north,
    // transposed.
    let t = f64::from(g.tile_size());
    for (what, shift, transpose) in [
        ("shifted a tile west", (-t, 0.0), false),
        ("shifted a tile north", (0.0, -t), false),
        ("transposed", (0.0, 0.0), true),
    ] {
        let wrong = classify(&expected_at(shift, transpose));
        let (w, _) = agreement(&got, &wrong);
        eprintln!("against the imagery {what}: {:.2} %", w * 100.0);
        assert!(
            w < 0.95,
            "the imagery {what} also agrees ({:.2} %)",
            w * 100.0
        );
    }
    // The root's imagery, coarser, still has the coast where it is.
    let (w, _) = agreement(&classify(&seaness_of(&frame_ancestor)), &expected);
    eprintln!("drawn with the root's imagery: {:.2} %", w * 100.0);
    assert!(
        w >= 0.95,
        "the ancestor's imagery is misplaced ({:.2} %)",
        w * 100.0
    );
    // Without imagery (the tint), the frame's classes do not follow the coast.
    let tint: Vec<f64> = frame_without
        .chunks(4)
        .map(|p| seaness([f64::from(p[0]), f64::from(p[1]), f64::from(p[2])]))
        .collect();
    let (w, _) = agreement(&classify(&tint), &expected);
    eprintln!("the tinted frame (no imagery): {:.2} %", w * 100.0);
    assert!(
        w < 0.95,
        "the frame without imagery also agrees ({:.2} %)",
        w * 100.0
    );
}
