//! Every real DEM in `../shared/data/dem/` builds, verifies, and its metadata states
//! the size, height range, CRS, extent and no-data count its README gives.

#![allow(clippy::unwrap_used)] // test helpers: a failed unwrap is a failed test

use tessera_server::builder::{BuildOptions, build};
use tessera_server::verify::verify;
use tessera_shared::{Pyramid, testdata};

#[test]
fn every_real_dem_builds_verifies_and_describes_itself() {
    let dir = tempfile::tempdir().unwrap();
    let mut built = 0;
    for f in testdata::DEMS {
        let Some(path) = testdata::dem_or_skip(f.name) else {
            continue;
        };
        let out = dir.path().join(format!("{}.tess", f.name));
        let opts = BuildOptions {
            scale: f.scale,
            offset: f.offset,
            ..BuildOptions::default()
        };
        let report = build(path.to_str().unwrap(), &out, &opts).unwrap();
        let v = verify(&out).unwrap();
        assert!(v.bad.is_empty(), "{}: {:?}", f.name, v.bad);
        assert!(v.tiles > 0);
        let p = Pyramid::open_file(&out).unwrap();
        let m = p.metadata();
        assert_eq!(
            m, &report.metadata,
            "{}: the report is what was written",
            f.name
        );
        assert_eq!((m.width, m.height), (f.width, f.height), "{}", f.name);
        // The README rounds float ranges to 0.1 m; integer inputs are exact.
        let tol = m.quantization.max_error
            + if m.quantization.max_error > 0.0 {
                0.05
            } else {
                1e-9
            };
        assert!(
            (m.min_height - f.min).abs() <= tol,
            "{}: min {} vs {}",
            f.name,
            m.min_height,
            f.min
        );
        assert!(
            (m.max_height - f.max).abs() <= tol,
            "{}: max {} vs {}",
            f.name,
            m.max_height,
            f.max
        );
        assert_eq!(m.nodata_count, f.nodata_count, "{}: no-data count", f.name);
        assert_eq!(
            m.georef.as_ref().and_then(|g| g.epsg),
            f.epsg,
            "{}: EPSG",
            f.name
        );
        if let Some(want) = f.extent {
            let got = m.georef.as_ref().unwrap().extent(m.width, m.height);
            for (g, w) in got.iter().zip(want) {
                assert!(
                    (g - w).abs() <= 1e-6 * w.abs().max(1.0),
                    "{}: extent {got:?} vs {want:?}",
                    f.name
                );
            }
        }
        assert_eq!(m.content_hash.len(), 16);
        built += 1;
    }
    eprintln!("{built} real DEMs built and verified");
}

/// The same input and options give the same bytes (the content hash is an identity).
#[test]
fn builds_are_deterministic() {
    let dir = tempfile::tempdir().unwrap();
    let opts = BuildOptions {
        tile_size: 128,
        ..BuildOptions::default()
    };
    let a = dir.path().join("a.tess");
    let b = dir.path().join("b.tess");
    build("synthetic:1000:5", &a, &opts).unwrap();
    build("synthetic:1000:5", &b, &opts).unwrap();
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    let c = dir.path().join("c.tess");
    build("synthetic:1000:6", &c, &opts).unwrap();
    let hash = |p: &std::path::Path| {
        Pyramid::open_file(p)
            .unwrap()
            .metadata()
            .content_hash
            .clone()
    };
    assert_ne!(hash(&a), hash(&c));
}
