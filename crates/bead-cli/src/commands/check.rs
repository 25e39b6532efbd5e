//! `bead check`: validate a scene and describe it.

use anyhow::Result;

use super::{load_scene, print};
use crate::args::CheckArgs;
use crate::report;

/// `bead check`: load (which validates) and describe the scene.
pub fn check(args: &CheckArgs) -> Result<()> {
    let scene = load_scene(&args.scene, &args.set)?;
    print(&report::check_text(&scene))
}
