//! COLMAP cameras ↔ the engine's: camera models ↔ [`Intrinsics`] + [`Distortion`], and a
//! COLMAP image with its camera → a [`Camera`] ([`camera_from_image`], the one place a
//! COLMAP pose becomes an engine pose).
//!
//! Exact for the models the engine's distortion can express: SIMPLE_PINHOLE, PINHOLE,
//! SIMPLE_RADIAL, RADIAL, OPENCV, FULL_OPENCV (radial-tangential with the rational
//! k4..k6), and OPENCV_FISHEYE, SIMPLE_RADIAL_FISHEYE, RADIAL_FISHEYE (COLMAP's fisheye
//! models distort θ = atan r exactly like OpenCV's fisheye model). FOV and COLMAP's
//! thin-prism fisheye models have no engine equivalent: solve with OPENCV or
//! OPENCV_FISHEYE instead. The other way, OpenCV's thin-prism and tilt terms have no COLMAP
//! model ([`from_engine`] refuses them).

use glam::DMat3;
use shared_types::{Camera, Distortion, Intrinsics, WorldToCamera};

use crate::colmap::{CameraModel, ColmapCamera, ColmapImage, ColmapModel};

#[derive(Debug, thiserror::Error)]
pub enum ConvertError {
    #[error(
        "COLMAP camera {camera_id} uses model {model}, which the engine cannot represent{detail}; \
         run COLMAP with camera model OPENCV (or OPENCV_FISHEYE for wide lenses) instead"
    )]
    Unsupported {
        camera_id: u32,
        model: CameraModel,
        detail: String,
    },
    #[error("COLMAP image {image} uses camera {camera_id}, which is not among the model's cameras")]
    MissingCamera { image: String, camera_id: u32 },
    #[error(
        "a lens with OpenCV coefficients {coefficients:?} has thin-prism or tilted-sensor terms, \
         which no COLMAP camera model holds; recalibrate with OpenCV's rational model (8 \
         coefficients) or fewer"
    )]
    NoColmapModel { coefficients: Vec<f64> },
    #[error(
        "COLMAP camera {camera_id} has an image size of {width}×{height} that does not fit in 32 bits"
    )]
    Size {
        camera_id: u32,
        width: u64,
        height: u64,
    },
}

/// The engine's intrinsics and distortion for a COLMAP camera.
pub fn to_engine(cam: &ColmapCamera) -> Result<(Intrinsics, Distortion), ConvertError> {
    let p = &cam.params;
    let (width, height) = match (u32::try_from(cam.width), u32::try_from(cam.height)) {
        (Ok(w), Ok(h)) => (w, h),
        _ => {
            return Err(ConvertError::Size {
                camera_id: cam.id,
                width: cam.width,
                height: cam.height,
            });
        }
    };
    let (fx, fy, cx, cy, rest) = if cam.model.has_single_focal() {
        (p[0], p[0], p[1], p[2], &p[3..])
    } else {
        (p[0], p[1], p[2], p[3], &p[4..])
    };
    let intr = Intrinsics {
        width,
        height,
        fx,
        fy,
        cx,
        cy,
    };
    let unsupported = |detail: &str| ConvertError::Unsupported {
        camera_id: cam.id,
        model: cam.model,
        detail: detail.into(),
    };
    let opencv = |c: &[f64]| {
        Distortion::from_opencv_coefficients(c).expect("COLMAP's layouts have 4, 5 or 8 terms")
    };
    let dist = match cam.model {
        CameraModel::SimplePinhole | CameraModel::Pinhole => Distortion::None,
        CameraModel::SimpleRadial => opencv(&[rest[0], 0.0, 0.0, 0.0]),
        CameraModel::Radial => opencv(&[rest[0], rest[1], 0.0, 0.0]),
        CameraModel::Opencv => opencv(rest),
        // COLMAP's order k1 k2 p1 p2 k3 k4 k5 k6 is OpenCV's.
        CameraModel::FullOpencv => opencv(rest),
        CameraModel::OpencvFisheye => Distortion::Fisheye {
            k1: rest[0],
            k2: rest[1],
            k3: rest[2],
            k4: rest[3],
        },
        CameraModel::SimpleRadialFisheye => Distortion::Fisheye {
            k1: rest[0],
            k2: 0.0,
            k3: 0.0,
            k4: 0.0,
        },
        CameraModel::RadialFisheye => Distortion::Fisheye {
            k1: rest[0],
            k2: rest[1],
            k3: 0.0,
            k4: 0.0,
        },
        CameraModel::Fov | CameraModel::ThinPrismFisheye | CameraModel::RadTanThinPrismFisheye => {
            return Err(unsupported(""));
        }
    };
    Ok((intr, dist))
}

/// The engine camera `name` of a COLMAP `image` of `model`: its camera's intrinsics and
/// distortion ([`to_engine`]) and the image's world-to-camera pose, the rotation made
/// exactly orthonormal.
pub fn camera_from_image(
    model: &ColmapModel,
    image: &ColmapImage,
    name: &str,
) -> Result<Camera, ConvertError> {
    let cam = model
        .cameras
        .get(&image.camera_id)
        .ok_or_else(|| ConvertError::MissingCamera {
            image: image.name.clone(),
            camera_id: image.camera_id,
        })?;
    let (intrinsics, distortion) = to_engine(cam)?;
    Ok(Camera {
        name: name.to_string(),
        intrinsics,
        distortion,
        world_to_camera: WorldToCamera::from_parts(
            orthonormalise(image.rotation()),
            image.translation(),
        ),
    })
}

/// The nearest rotation (COLMAP's normalised quaternions are orthonormal to ~1e-16 already;
/// this guards models written by other tools).
fn orthonormalise(r: DMat3) -> DMat3 {
    let m = nalgebra::Matrix3::from_fn(|i, j| r.col(j)[i]);
    let svd = m.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return r;
    };
    let mut q = u * vt;
    if q.determinant() < 0.0 {
        let mut u2 = u;
        u2.column_mut(2).neg_mut();
        q = u2 * vt;
    }
    crate::similarity::to_dmat3(&q)
}

/// The PINHOLE COLMAP camera of engine intrinsics (what [`from_engine`] gives for a lens
/// without distortion, infallibly).
pub fn pinhole_from_engine(id: u32, intr: &Intrinsics) -> ColmapCamera {
    ColmapCamera {
        id,
        model: CameraModel::Pinhole,
        width: intr.width as u64,
        height: intr.height as u64,
        params: vec![intr.fx, intr.fy, intr.cx, intr.cy],
    }
}

/// The COLMAP model and parameters for engine intrinsics and distortion (PINHOLE, OPENCV,
/// FULL_OPENCV when k3..k6 are not all zero, or OPENCV_FISHEYE). OpenCV's thin-prism and
/// tilted-sensor terms have no COLMAP model: refused.
pub fn from_engine(
    id: u32,
    intr: &Intrinsics,
    dist: &Distortion,
) -> Result<ColmapCamera, ConvertError> {
    let Intrinsics {
        width,
        height,
        fx,
        fy,
        cx,
        cy,
    } = *intr;
    let (model, params) = match *dist {
        Distortion::None => (CameraModel::Pinhole, vec![fx, fy, cx, cy]),
        Distortion::Opencv { .. } => {
            let c = dist.coefficients();
            match c.len() {
                5 if c[4] == 0.0 => (CameraModel::Opencv, [&[fx, fy, cx, cy], &c[..4]].concat()),
                5 | 8 => {
                    let mut params = vec![fx, fy, cx, cy];
                    params.extend(&c);
                    params.resize(12, 0.0);
                    (CameraModel::FullOpencv, params)
                }
                _ => {
                    return Err(ConvertError::NoColmapModel { coefficients: c });
                }
            }
        }
        Distortion::Fisheye { k1, k2, k3, k4 } => (
            CameraModel::OpencvFisheye,
            vec![fx, fy, cx, cy, k1, k2, k3, k4],
        ),
    };
    Ok(ColmapCamera {
        id,
        model,
        width: width as u64,
        height: height as u64,
        params,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn engine_cameras_round_trip_through_colmap_models() {
        let intr = Intrinsics {
            width: 640,
            height: 480,
            fx: 500.0,
            fy: 501.0,
            cx: 320.5,
            cy: 240.25,
        };
        for dist in [
            Distortion::None,
            Distortion::radial_tangential(-0.1, 0.02, 1e-3, -2e-3, 0.0),
            Distortion::radial_tangential(-0.1, 0.02, 1e-3, -2e-3, 0.004),
            // The rational model (OpenCV's 8 coefficients) is FULL_OPENCV.
            Distortion::from_opencv_coefficients(&[
                -0.1, 0.02, 1e-3, -2e-3, 0.004, 0.3, -0.05, 0.01,
            ])
            .unwrap(),
            Distortion::Fisheye {
                k1: 0.05,
                k2: -0.01,
                k3: 0.002,
                k4: -1e-4,
            },
        ] {
            let cam = from_engine(7, &intr, &dist).unwrap();
            assert_eq!(cam.params.len(), cam.model.num_params());
            assert_eq!(to_engine(&cam).unwrap(), (intr, dist));
        }
    }

    #[test]
    fn single_focal_models_and_unsupported_ones() {
        let c = ColmapCamera::new(
            1,
            CameraModel::SimpleRadial,
            100,
            80,
            vec![90.0, 50.0, 40.0, 0.1],
        )
        .unwrap();
        let (i, d) = to_engine(&c).unwrap();
        assert_eq!((i.fx, i.fy, i.cx, i.cy), (90.0, 90.0, 50.0, 40.0));
        assert_eq!(d, Distortion::radial_tangential(0.1, 0.0, 0.0, 0.0, 0.0));
        // FULL_OPENCV with rational terms is the engine's OpenCV model, not a refusal.
        let c = ColmapCamera::new(
            3,
            CameraModel::FullOpencv,
            100,
            80,
            vec![
                90.0, 91.0, 50.0, 40.0, 0.1, 0.01, 1e-3, 2e-3, 0.001, 0.2, 0.03, -0.004,
            ],
        )
        .unwrap();
        let (_, d) = to_engine(&c).unwrap();
        assert_eq!(
            d.coefficients(),
            [0.1, 0.01, 1e-3, 2e-3, 0.001, 0.2, 0.03, -0.004]
        );
        // Thin prism has no COLMAP model.
        let prism = Distortion::from_opencv_coefficients(&[
            0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1e-3, 0.0, 0.0, 0.0,
        ])
        .unwrap();
        let e = from_engine(1, &i, &prism).unwrap_err().to_string();
        assert!(e.contains("thin-prism"), "{e}");
        let c = ColmapCamera::new(
            2,
            CameraModel::Fov,
            100,
            80,
            vec![90.0, 90.0, 50.0, 40.0, 0.9],
        )
        .unwrap();
        let e = to_engine(&c).unwrap_err().to_string();
        assert!(e.contains("FOV") && e.contains("OPENCV"), "{e}");
    }
}
