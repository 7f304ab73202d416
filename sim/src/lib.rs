//! An exact simulator of the wheel-legged robot's navigation task (the paper's "Robot and
//! Environment" and "Reward" sections).
//!
//! - [`obstacle`]: the three obstacle kinds and their boxes.
//! - [`state`]: the robot's pose and leg configuration on the action lattice.
//! - [`collision`]: the robot's parts and exact collision with parry3d.
//! - [`height_map`]: the robot-centred height map the policy sees.
//! - [`reward`]: the reward terms.
//! - [`env`]: one episode: reset, step, observe.
//! - [`scenario`] and [`scenario_file`]: navigation problems and their JSON files.
//! - [`generate`]: scene generators for the five behaviours and for complex scenes, and the
//!   memory of failed scenes ([`failure_memory`]).
//! - [`planner`]: exact shortest-path search over the action set.
//! - [`local_plan`]: that search on the robot's own map, for the last metres.
//! - [`render`]: PNG pictures of scenes and height maps.
//!
//! The robot's geometry and kinematics come from `wheelleg-runtime`, the crate that runs on the
//! robot: what is simulated is what is controlled.

pub mod collision;
pub mod env;
pub mod failure_memory;
pub mod generate;
pub mod height_map;
pub mod local_plan;
pub mod obstacle;
pub mod planner;
pub mod render;
pub mod reward;
pub mod scenario;
pub mod scenario_file;
pub mod state;

use std::io::Write;
use std::path::Path;

/// Writes `bytes` to `path` atomically: into a temporary file beside it, synced, then renamed
/// over the target. A crash leaves either the old file or the new one, never half of one.
pub fn atomic_write(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path.file_name().ok_or_else(|| {
        std::io::Error::new(std::io::ErrorKind::InvalidInput, "path has no file name")
    })?;
    let tmp = dir.join(format!(".{}.tmp", name.to_string_lossy()));
    {
        let mut file = std::fs::File::create(&tmp)?;
        file.write_all(bytes)?;
        file.sync_all()?;
    }
    std::fs::rename(&tmp, path)
}
