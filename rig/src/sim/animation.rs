//! Animation: where an object is at a scene time, from its keyframes.

use glam::{DQuat, DVec3};

use super::schema::ObjectSection;

/// Rigid pose of an object at scene time `t`: keyframes interpolated linearly (position)
/// and by slerp (rotation), held constant before the first and after the last.
pub(crate) fn object_pose(o: &ObjectSection, t: f64) -> (DQuat, DVec3) {
    let quat = |r: [f64; 3]| {
        DQuat::from_rotation_z(r[2].to_radians())
            * DQuat::from_rotation_y(r[1].to_radians())
            * DQuat::from_rotation_x(r[0].to_radians())
    };
    let k = &o.keyframes;
    if k.is_empty() {
        return (quat(o.rotation), DVec3::from_array(o.position));
    }
    if t <= k[0].t {
        return (quat(k[0].rotation), DVec3::from_array(k[0].position));
    }
    for w in k.windows(2) {
        if t <= w[1].t {
            let s = (t - w[0].t) / (w[1].t - w[0].t);
            let p = DVec3::from_array(w[0].position).lerp(DVec3::from_array(w[1].position), s);
            return (quat(w[0].rotation).slerp(quat(w[1].rotation), s), p);
        }
    }
    let last = k[k.len() - 1];
    (quat(last.rotation), DVec3::from_array(last.position))
}
