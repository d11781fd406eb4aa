//! `sdslam cameras`: what cameras this machine has, and the modes each offers.

use sdslam::camera::device::{format::describe_modes, list_cameras};
use sdslam::Result;

pub fn cameras() -> Result<()> {
    let cams = list_cameras();
    if cams.is_empty() {
        out!(
            "no cameras found (no V4L2 capture devices{})",
            if cfg!(feature = "libcamera") {
                " and no libcamera cameras"
            } else {
                ""
            }
        );
        return Ok(());
    }
    for c in &cams {
        out!("{}  {}", c.spec, c.name);
        match &c.error {
            Some(e) => out!("    cannot query: {e}"),
            None => {
                for part in describe_modes(&c.modes).split("; ") {
                    out!("    {part}");
                }
            }
        }
    }
    Ok(())
}
