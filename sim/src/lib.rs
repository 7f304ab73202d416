//! An exact simulator of the wheel-legged robot's navigation task (the paper's "Robot and
//! Environment" and "Reward" sections).
//!
//! - [`obstacle`]: the three obstacle kinds and their boxes.
//! - [`robot`]: the robot as simulated, its geometry and action lattice.
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
//! - [`render`]: PNG pictures of scenes and height maps (plotters).
//! - [`seeds`]: the seeds by purpose (training, held-out, calibration, validation, labels).
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
pub mod robot;
pub mod scenario;
pub mod scenario_file;
pub mod seeds;
pub mod state;

use robot::SimulatedRobot;
use std::io::Write;
use std::path::Path;
use std::sync::{Mutex, OnceLock};

/// Values worked out once per simulated robot: the shipped robot's, and every other's met so
/// far.
pub(crate) struct PerRobot<T: 'static> {
    shipped: OnceLock<T>,
    others: Mutex<Vec<(SimulatedRobot, &'static T)>>,
}

impl<T: Send + Sync + 'static> PerRobot<T> {
    /// An empty cache, for a `static`.
    pub(crate) const fn new() -> Self {
        PerRobot {
            shipped: OnceLock::new(),
            others: Mutex::new(Vec::new()),
        }
    }

    /// The value for `robot`, built by `build` on first use. Values live as long as the
    /// program: a run simulates one robot or a few, and a step must not wait on a value's
    /// lifetime. The shipped robot's is reached without a lock.
    pub(crate) fn get(
        &'static self,
        robot: &SimulatedRobot,
        build: impl FnOnce(&SimulatedRobot) -> T,
    ) -> &'static T {
        if *robot == SimulatedRobot::SHIPPED {
            return self.shipped.get_or_init(|| build(&SimulatedRobot::SHIPPED));
        }
        // A poisoned lock only means another thread panicked mid-insert: the list still holds
        // finished values.
        let mut others = self.others.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, value)) = others.iter().find(|(r, _)| r == robot) {
            return value;
        }
        let value: &'static T = Box::leak(Box::new(build(robot)));
        others.push((*robot, value));
        value
    }
}

/// Writes `bytes` to `path` atomically: into a temporary file beside it (so the rename stays
/// on one file system), synced, then renamed over the target. A crash leaves either the old
/// file or the new one, never half of one. Every file the project saves goes through here.
pub fn atomic_write(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let tmp = atomic_temp_path(path)?;
    let result = (|| {
        let mut file = std::fs::File::create(&tmp)?;
        file.write_all(bytes)?;
        file.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        // Best effort: the error that matters is the one being returned.
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// `dir/.name.tmp` beside `path`: where [`atomic_write`] writes before the rename.
pub fn atomic_temp_path(path: &Path) -> std::io::Result<std::path::PathBuf> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = path.file_name().ok_or_else(|| {
        std::io::Error::new(std::io::ErrorKind::InvalidInput, "path has no file name")
    })?;
    Ok(dir.join(format!(".{}.tmp", name.to_string_lossy())))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_atomic_write_replaces_the_file_and_leaves_no_temporary() {
        let dir = std::env::temp_dir().join(format!("wheelleg-atomic-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("policy.wlw");
        atomic_write(&path, b"first").unwrap();
        atomic_write(&path, b"second").unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"second");
        assert!(!atomic_temp_path(&path).unwrap().exists());
        assert!(atomic_write(&dir.join("missing").join("x.wlw"), b"x").is_err());
        assert!(atomic_write(Path::new("/"), b"x").is_err(), "no file name");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
