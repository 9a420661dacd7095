//! Fuzzed readers of exported point maps (MASt3R-style `.npy` files and `.npz` archives)
//! and of point-cloud PLYs (`points.ply`, `shared_types::points`): damaged copies of
//! valid files (`shared_types::fuzz`) must give an error or a value, never a panic, an
//! abort or an allocation a damaged header asked for.
//! `PROPTEST_CASES` sets the number of cases.

use std::path::{Path, PathBuf};

use pointinit::npy::{self, OutputNames, PairMaps, PointMap};
use proptest::prelude::*;
use shared_types::PointCloud;
use shared_types::fuzz::{self, damaged, within_budget};
use shared_types::points::{read_points_ply, write_points_ply};

fn maps() -> PairMaps {
    let map = |z: f32| PointMap {
        width: 6,
        height: 4,
        points: (0..24)
            .map(|i| [i as f32 * 0.1, -(i as f32) * 0.05, z])
            .collect(),
        confidence: Some((0..24).map(|i| 1.0 + i as f32).collect()),
    };
    PairMaps {
        first: map(2.0),
        second: map(2.5),
    }
}

/// The files a pair export writes, as (path relative to the maps folder, bytes).
fn export(npz: bool) -> Vec<(PathBuf, Vec<u8>)> {
    let dir = tempfile::tempdir().unwrap();
    let names = OutputNames::default();
    if npz {
        npy::write_pair_npz(dir.path(), "cam0", "cam1", &maps(), &names).unwrap();
    } else {
        npy::write_pair_dir(dir.path(), "cam0", "cam1", &maps(), &names).unwrap();
    }
    let mut files = Vec::new();
    collect(dir.path(), dir.path(), &mut files);
    files.sort();
    files
}

fn collect(root: &Path, dir: &Path, out: &mut Vec<(PathBuf, Vec<u8>)>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            collect(root, &path, out);
        } else {
            let bytes = std::fs::read(&path).unwrap();
            out.push((path.strip_prefix(root).unwrap().to_path_buf(), bytes));
        }
    }
}

/// The export of `npz` or a folder of `.npy`, with its file number `which` replaced by
/// `bytes`, read back as a pair.
fn read_damaged(npz: bool, which: usize, bytes: &[u8]) -> Result<(), TestCaseError> {
    let dir = tempfile::tempdir().unwrap();
    let files = export(npz);
    for (i, (rel, valid)) in files.iter().enumerate() {
        let path = dir.path().join(rel);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(
            &path,
            if i == which % files.len() {
                bytes
            } else {
                valid
            },
        )
        .unwrap();
    }
    let names = OutputNames::default();
    within_budget(|| npy::read_pair(dir.path(), "cam0", "cam1", &names))
}

fn cloud_file(with_time: bool) -> Vec<u8> {
    let n = 10;
    let cloud = PointCloud {
        xyz: (0..n).map(|i| [i as f32, 0.5, -(i as f32)]).collect(),
        rgb: (0..n).map(|i| [i as u8 * 20, 100, 7]).collect(),
        time: with_time.then(|| (0..n).map(|i| i as f32 / 10.0).collect()),
        time_span: with_time.then(|| vec![0.0; n]),
    };
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("points.ply");
    write_points_ply(&cloud, &path).unwrap();
    std::fs::read(&path).unwrap()
}

proptest! {
    #![proptest_config(fuzz::config(1))]

    #[test]
    fn npy_files(
        (which, bytes) in (0..4usize).prop_flat_map(|w| (Just(w), damaged(export(false)[w].1.clone())))
    ) {
        read_damaged(false, which, &bytes)?;
    }

    #[test]
    fn npz_archives(bytes in damaged(export(true)[0].1.clone())) {
        read_damaged(true, 0, &bytes)?;
    }

    #[test]
    fn single_npy(bytes in damaged(export(false)[0].1.clone())) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("depth.npy");
        std::fs::write(&path, &bytes).unwrap();
        within_budget(|| npy::read_npy(&path))?;
    }

    #[test]
    fn points_ply(
        bytes in prop_oneof![damaged(cloud_file(false)), damaged(cloud_file(true))]
    ) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("points.ply");
        std::fs::write(&path, &bytes).unwrap();
        within_budget(|| read_points_ply(&path))?;
    }
}

/// A version-3 header whose 4-byte length field claims 660 MB (a case the fuzzer found):
/// a clear error naming the file, with no allocation of that size.
#[test]
fn a_header_length_past_numpys_limit_is_refused_without_allocating_it() {
    let mut bytes = b"\x93NUMPY\x03\x00".to_vec();
    bytes.extend_from_slice(&662_372_470u32.to_le_bytes());
    bytes.extend_from_slice(b"{'descr': '<f4', 'fortran_order': False, 'shape': (2, ), }\n");
    bytes.extend_from_slice(&[0; 8]);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("pts1.npy");
    std::fs::write(&path, &bytes).unwrap();
    within_budget(|| {
        let err = npy::read_npy(&path).unwrap_err().to_string();
        assert!(
            err.contains("pts1.npy") && err.contains("662372470"),
            "{err}"
        );
    })
    .unwrap();
}
