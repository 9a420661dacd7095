//! COLMAP's camera models: numeric ID (binary files), name (text files and the command
//! line) and parameter layout. Covers every model of COLMAP 3.8 plus
//! `RAD_TAN_THIN_PRISM_FISHEYE` (added in COLMAP 3.11).

use std::fmt;
use std::str::FromStr;

/// A COLMAP camera model.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CameraModel {
    SimplePinhole,
    Pinhole,
    SimpleRadial,
    Radial,
    Opencv,
    OpencvFisheye,
    FullOpencv,
    Fov,
    SimpleRadialFisheye,
    RadialFisheye,
    ThinPrismFisheye,
    RadTanThinPrismFisheye,
}

impl CameraModel {
    pub const ALL: [CameraModel; 12] = [
        Self::SimplePinhole,
        Self::Pinhole,
        Self::SimpleRadial,
        Self::Radial,
        Self::Opencv,
        Self::OpencvFisheye,
        Self::FullOpencv,
        Self::Fov,
        Self::SimpleRadialFisheye,
        Self::RadialFisheye,
        Self::ThinPrismFisheye,
        Self::RadTanThinPrismFisheye,
    ];

    /// COLMAP's model ID as stored in `cameras.bin`.
    pub fn id(self) -> i32 {
        Self::ALL
            .iter()
            .position(|&m| m == self)
            .map_or(-1, |i| i as i32)
    }

    pub fn from_id(id: i32) -> Option<Self> {
        usize::try_from(id)
            .ok()
            .and_then(|i| Self::ALL.get(i).copied())
    }

    /// COLMAP's model name as in `cameras.txt` and `--ImageReader.camera_model`.
    pub fn name(self) -> &'static str {
        match self {
            Self::SimplePinhole => "SIMPLE_PINHOLE",
            Self::Pinhole => "PINHOLE",
            Self::SimpleRadial => "SIMPLE_RADIAL",
            Self::Radial => "RADIAL",
            Self::Opencv => "OPENCV",
            Self::OpencvFisheye => "OPENCV_FISHEYE",
            Self::FullOpencv => "FULL_OPENCV",
            Self::Fov => "FOV",
            Self::SimpleRadialFisheye => "SIMPLE_RADIAL_FISHEYE",
            Self::RadialFisheye => "RADIAL_FISHEYE",
            Self::ThinPrismFisheye => "THIN_PRISM_FISHEYE",
            Self::RadTanThinPrismFisheye => "RAD_TAN_THIN_PRISM_FISHEYE",
        }
    }

    /// Parameter names in COLMAP's order.
    pub fn param_names(self) -> &'static [&'static str] {
        match self {
            Self::SimplePinhole => &["f", "cx", "cy"],
            Self::Pinhole => &["fx", "fy", "cx", "cy"],
            Self::SimpleRadial => &["f", "cx", "cy", "k"],
            Self::Radial => &["f", "cx", "cy", "k1", "k2"],
            Self::Opencv => &["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"],
            Self::OpencvFisheye => &["fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"],
            Self::FullOpencv => &[
                "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6",
            ],
            Self::Fov => &["fx", "fy", "cx", "cy", "omega"],
            Self::SimpleRadialFisheye => &["f", "cx", "cy", "k"],
            Self::RadialFisheye => &["f", "cx", "cy", "k1", "k2"],
            Self::ThinPrismFisheye => &[
                "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "sx1", "sy1",
            ],
            Self::RadTanThinPrismFisheye => &[
                "fx", "fy", "cx", "cy", "k0", "k1", "k2", "k3", "k4", "k5", "p0", "p1", "s0", "s1",
                "s2", "s3",
            ],
        }
    }

    pub fn num_params(self) -> usize {
        self.param_names().len()
    }

    /// True for models with a single focal length (`f`).
    pub fn has_single_focal(self) -> bool {
        self.param_names()[0] == "f"
    }
}

impl fmt::Display for CameraModel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for CameraModel {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let upper = s.trim().to_ascii_uppercase();
        Self::ALL
            .into_iter()
            .find(|m| m.name() == upper)
            .ok_or_else(|| {
                let names: Vec<_> = Self::ALL.iter().map(|m| m.name()).collect();
                format!(
                    "unknown COLMAP camera model {s:?}; known: {}",
                    names.join(", ")
                )
            })
    }
}

impl serde::Serialize for CameraModel {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

impl<'de> serde::Deserialize<'de> for CameraModel {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_names_and_param_counts_match_colmap() {
        let expected = [3, 4, 4, 5, 8, 8, 12, 5, 4, 5, 12, 16];
        for (i, m) in CameraModel::ALL.into_iter().enumerate() {
            assert_eq!(m.id(), i as i32);
            assert_eq!(CameraModel::from_id(i as i32), Some(m));
            assert_eq!(m.name().parse::<CameraModel>().unwrap(), m);
            assert_eq!(m.num_params(), expected[i], "{m}");
        }
        assert_eq!(CameraModel::from_id(12), None);
        assert!("opencv".parse::<CameraModel>().is_ok());
        assert!("BROWN".parse::<CameraModel>().is_err());
    }
}
