//! Model file round trips; truncated, foreign and corrupt files are typed errors.

use crate::common;

use common::{SceneSpec, random_scene};
use splat4d::model::ColourDegrees;
use splat4d::model::file::{HEADER_LEN, ModelFileError, parse_model};
use splat4d::{Gaussians, TimeMapping, load_model, save_model};
use std::path::Path;

fn sample() -> Gaussians<f32> {
    let mut m = random_scene(
        5,
        SceneSpec {
            count: 7,
            degrees: ColourDegrees {
                spatial: 2,
                temporal: 1,
            },
            ..SceneSpec::default()
        },
    )
    .cast::<f32>();
    m.active = ColourDegrees {
        spatial: 1,
        temporal: 0,
    };
    m.time = TimeMapping::frames_over_30(12.5, 60.0, 10.0);
    m
}

#[test]
fn save_and_load_round_trip_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("model.s4d");
    let m = sample();
    save_model(&m, &path).unwrap();
    let names: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, ["model.s4d"], "temporary file renamed away");
    let back = load_model(&path).unwrap();
    assert_eq!(back, m);
    assert_eq!(back.time.model_time(12.5 + 1.0), 2.0);

    let empty = Gaussians::<f32>::new(ColourDegrees::FULL, TimeMapping::default());
    save_model(&empty, &path).unwrap();
    assert_eq!(load_model(&path).unwrap(), empty);
}

#[test]
fn every_truncation_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("model.s4d");
    save_model(&sample(), &path).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    for len in 0..bytes.len() {
        let err = parse_model(&bytes[..len], Path::new("cut.s4d")).unwrap_err();
        assert!(
            matches!(
                err,
                ModelFileError::SizeMismatch { .. } | ModelFileError::NotAModel { .. }
            ),
            "length {len}: {err}"
        );
        assert!(err.to_string().contains("cut.s4d"));
    }
    let mut longer = bytes.clone();
    longer.extend_from_slice(&[0; 4]);
    assert!(matches!(
        parse_model(&longer, Path::new("x")),
        Err(ModelFileError::SizeMismatch { .. })
    ));
}

#[test]
fn foreign_and_corrupt_files_are_rejected() {
    let p = Path::new("photo.png");
    let png = b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR\0\0\0\x01\0\0\0\x01\x08\x02\0\0\0";
    assert!(matches!(
        parse_model(png, p),
        Err(ModelFileError::NotAModel { .. })
    ));
    assert!(matches!(
        parse_model(b"ply\nformat binary_little_endian 1.0\n", p),
        Err(ModelFileError::NotAModel { .. })
    ));

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("model.s4d");
    save_model(&sample(), &path).unwrap();
    let good = std::fs::read(&path).unwrap();

    let mut v = good.clone();
    v[8] = 99; // version
    let err = parse_model(&v, p).unwrap_err();
    assert!(
        matches!(err, ModelFileError::UnsupportedVersion { version: 99, .. }),
        "{err}"
    );

    let mut v = good.clone();
    v[24] = 7; // spatial degree out of range
    assert!(matches!(
        parse_model(&v, p),
        Err(ModelFileError::BadHeader { .. })
    ));

    let mut v = good.clone();
    v[16..24].copy_from_slice(&u64::MAX.to_le_bytes()); // absurd count: no huge allocation
    assert!(matches!(
        parse_model(&v, p),
        Err(ModelFileError::SizeMismatch { .. })
    ));

    let mut v = good.clone();
    v[40..48].copy_from_slice(&f64::NAN.to_le_bytes()); // time mapping
    assert!(matches!(
        parse_model(&v, p),
        Err(ModelFileError::BadHeader { .. })
    ));
    assert!(good.len() > HEADER_LEN);

    let missing = dir.path().join("nope.s4d");
    assert!(matches!(
        load_model(&missing),
        Err(ModelFileError::Io { .. })
    ));

    let mut broken = sample();
    broken.means.pop();
    assert!(matches!(
        save_model(&broken, &path),
        Err(ModelFileError::Inconsistent { .. })
    ));
}
