//! The init stage's settings and its fallback chain (point maps → sparse → random).

use glam::DVec3;
use pointinit::{
    InitConfig, InitError, InitInputs, Pairs, PairsKeyword, Source, UsedSource, run_init,
};
use shared_types::{Camera, CameraSet, Intrinsics, NoProgress, WorldToCamera};

fn rig() -> CameraSet {
    let cams = [
        DVec3::new(3.0, -2.0, 1.6),
        DVec3::new(3.2, 1.2, 1.5),
        DVec3::new(-1.0, -3.3, 1.7),
        DVec3::new(1.2, -3.2, 1.2),
    ];
    CameraSet::new(
        cams.iter()
            .enumerate()
            .map(|(i, eye)| Camera {
                name: format!("cam{i}"),
                intrinsics: Intrinsics::from_hfov(160, 120, 70.0),
                distortion: Default::default(),
                world_to_camera: WorldToCamera::look_at(*eye, DVec3::new(0.0, 0.0, 0.6), DVec3::Z)
                    .unwrap(),
            })
            .collect(),
    )
}

#[test]
fn config_reads_from_toml() {
    let c: InitConfig = toml::from_str(
        r#"
        source = "npy"
        pointmaps = "work/pointmaps"
        pairs = [["cam0", "cam1"], ["cam2", "cam3"]]
        min_confidence = 3.0
        output_names = { pts1 = "pts3d", conf1 = "conf", pts2 = "pts3d_in_other_view", conf2 = "conf2" }
        "#,
    )
    .unwrap();
    assert_eq!(c.source, Source::Npy);
    assert_eq!(
        c.pairs,
        Pairs::List(vec![
            ["cam0".into(), "cam1".into()],
            ["cam2".into(), "cam3".into()]
        ])
    );
    assert_eq!(c.output_names.pts2, "pts3d_in_other_view");
    assert_eq!(c.voxel_size, InitConfig::default().voxel_size);
    let c: InitConfig = toml::from_str("pairs = \"all\"\nsource = \"random\"").unwrap();
    assert_eq!(c.pairs, Pairs::Keyword(PairsKeyword::All));
    assert!(toml::from_str::<InitConfig>("voxel = 0.1").is_err());
    assert!(toml::from_str::<InitConfig>("pairs = \"some\"").is_err());
    // Round trip.
    let text = toml::to_string(&InitConfig::default()).unwrap();
    assert_eq!(
        toml::from_str::<InitConfig>(&text).unwrap(),
        InitConfig::default()
    );
}

#[test]
fn without_point_maps_the_sparse_points_are_used_then_a_random_cloud() {
    let tmp = tempfile::tempdir().unwrap();
    let sparse = tmp.path().join("points3d.ply");
    let cloud = shared_types::PointCloud {
        xyz: vec![[0.0, 0.0, 0.5], [0.2, 0.1, 0.7], [-0.3, 0.2, 0.4]],
        rgb: vec![[10, 20, 30]; 3],
        time: None,
        time_span: None,
    };
    shared_types::points::write_points_ply(&cloud, &sparse).unwrap();
    let mut inputs = InitInputs {
        cameras: rig(),
        images: vec![],
        sparse: Some(sparse),
        moments: vec![],
        plate_frames: Vec::new(),
        stills: Vec::new(),
    };
    let out = tmp.path().join("init");
    let exact = InitConfig {
        min_points: 0,
        ..InitConfig::default()
    };
    let report = run_init(&inputs, &exact, &out, &NoProgress).unwrap();
    assert_eq!(report.source, UsedSource::Sparse);
    assert_eq!(report.fallbacks.len(), 1);
    let got = shared_types::points::read_points_ply(&out.join("points.ply")).unwrap();
    assert_eq!((&got.xyz, &got.rgb), (&cloud.xyz, &cloud.rgb));
    // Three points are too few to train from (min_points 1000 by default): a random cloud
    // is added to them, and the report says so.
    let topped = InitConfig {
        random_points: 2000,
        ..InitConfig::default()
    };
    let report = run_init(&inputs, &topped, &out, &NoProgress).unwrap();
    assert_eq!(report.source, UsedSource::Sparse);
    assert!(
        report.fallbacks.iter().any(|f| f.contains("min_points")),
        "{:?}",
        report.fallbacks
    );
    let got = shared_types::points::read_points_ply(&out.join("points.ply")).unwrap();
    assert_eq!(got.xyz.len(), 2003);
    assert!(cloud.xyz.iter().all(|p| got.xyz.contains(p)));

    inputs.sparse = None;
    let config = InitConfig {
        random_points: 2000,
        seed: 5,
        ..InitConfig::default()
    };
    let report = run_init(&inputs, &config, &out, &NoProgress).unwrap();
    assert_eq!(report.source, UsedSource::Random);
    assert_eq!(report.fallbacks.len(), 2, "{:?}", report.fallbacks);
    let got = shared_types::points::read_points_ply(&out.join("points.ply")).unwrap();
    assert_eq!(got.xyz.len(), 2000);
    for p in &got.xyz {
        let p = DVec3::from_array(p.map(f64::from));
        for c in &inputs.cameras.cameras {
            let (px, _) = c.project(p).expect("in front of every camera");
            assert!(px.x >= 0.0 && px.y >= 0.0 && px.x < 160.0 && px.y < 120.0);
        }
    }
    // Seeded: the same cloud again.
    run_init(&inputs, &config, &tmp.path().join("again"), &NoProgress).unwrap();
    assert_eq!(
        std::fs::read(out.join("points.ply")).unwrap(),
        std::fs::read(tmp.path().join("again/points.ply")).unwrap()
    );
    // Asked for random: no fallback to announce.
    let config = InitConfig {
        source: Source::Random,
        ..config
    };
    let report = run_init(&inputs, &config, &out, &NoProgress).unwrap();
    assert!(report.fallbacks.is_empty());
}

#[test]
fn bad_settings_and_inputs_are_typed_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let inputs = InitInputs {
        cameras: rig(),
        images: vec![],
        sparse: None,
        moments: vec![],
        plate_frames: Vec::new(),
        stills: Vec::new(),
    };
    let out = tmp.path().join("init");
    let onnx = InitConfig {
        source: Source::Onnx,
        ..InitConfig::default()
    };
    assert!(matches!(
        run_init(&inputs, &onnx, &out, &NoProgress),
        Err(InitError::Config(_))
    ));
    let npy = InitConfig {
        source: Source::Npy,
        pointmaps: Some(tmp.path().join("nowhere")),
        ..InitConfig::default()
    };
    let e = run_init(&inputs, &npy, &out, &NoProgress).unwrap_err();
    assert!(e.to_string().contains("nowhere"), "{e}");
    let mut bad = inputs.clone();
    bad.images.push(pointinit::ViewImage {
        camera: "cam9".into(),
        path: tmp.path().join("x.png"),
        time: 0.0,
    });
    assert!(matches!(
        run_init(&bad, &InitConfig::default(), &out, &NoProgress),
        Err(InitError::Config(_))
    ));
    // A frame of the wrong size.
    let png = tmp.path().join("small.png");
    image::RgbImage::new(16, 12).save(&png).unwrap();
    let mut bad = inputs.clone();
    bad.images.push(pointinit::ViewImage {
        camera: "cam0".into(),
        path: png,
        time: 0.0,
    });
    std::fs::create_dir_all(tmp.path().join("maps")).unwrap();
    let npy = InitConfig {
        source: Source::Npy,
        pointmaps: Some(tmp.path().join("maps")),
        ..InitConfig::default()
    };
    assert!(matches!(
        run_init(&bad, &npy, &out, &NoProgress),
        Err(InitError::ImageSize { .. })
    ));
    assert!(!out.join("points.ply").exists());
}
