//! Config files: TOML text and files (with `extends`), the keys of retired experiments, and what
//! a resume from a stored config would change.

use super::*;
use std::fmt;
use std::path::PathBuf;
use wheelleg_robot::RobotDescription;

/// Why a config cannot be read or used; every message names the file and the key.
#[derive(Debug)]
pub enum ConfigError {
    /// The file could not be read.
    Io {
        /// The file.
        path: PathBuf,
        /// What the system said.
        error: std::io::Error,
    },
    /// The text is not TOML, or a key has the wrong type or name (the message names it).
    Toml(String),
    /// A key of an experiment that measured no gain, set so as to switch it on.
    Retired {
        /// `section.key`.
        key: String,
        /// Its value in the file.
        value: String,
    },
    /// `extends` names no config file, or the chain is too long.
    Extends(String),
    /// A key outside its range (the message names it and the range).
    Invalid(String),
    /// The robot description (`run.robot` or `--robot`) does not read or cannot be simulated.
    Robot(String),
    /// A stored config (a checkpoint's) does not parse, or a config does not serialize.
    Stored(String),
    /// One of the above, in the file `path`.
    In {
        /// The file.
        path: PathBuf,
        /// What is wrong in it.
        error: Box<ConfigError>,
    },
    /// One of the above, in the config `base` that `path` extends.
    Base {
        /// The extending file.
        path: PathBuf,
        /// The base it names.
        base: String,
        /// What is wrong in the base.
        error: Box<ConfigError>,
    },
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ConfigError::Io { path, error } => {
                write!(f, "cannot read config {}: {error}", path.display())
            }
            ConfigError::Toml(what)
            | ConfigError::Extends(what)
            | ConfigError::Invalid(what)
            | ConfigError::Stored(what) => f.write_str(what),
            ConfigError::Retired { key, value } => write!(
                f,
                "{key} = {value}: that experiment measured no gain and was removed \
                 (docs/results.md, \"Experiments that measured no gain\"); drop the key"
            ),
            ConfigError::Robot(what) => f.write_str(what),
            ConfigError::In { path, error } => write!(f, "config {}: {error}", path.display()),
            ConfigError::Base { path, base, error } => {
                write!(f, "config {} extends {base}: {error}", path.display())
            }
        }
    }
}

impl std::error::Error for ConfigError {}

impl ConfigError {
    fn in_file(self, path: &Path) -> ConfigError {
        ConfigError::In {
            path: path.to_path_buf(),
            error: Box::new(self),
        }
    }
}

/// `run` keys a resumed run may change: its budget and its early stop, the re-sampling of failed
/// scenes and the shares of composed and exit scenes (which only change which scenes come next).
const RESUMABLE_CHANGES: [&str; 9] = [
    "total_env_steps",
    "stop_success_rate",
    "stop_window",
    "composed_share",
    "exit_share",
    "exit_behaviour",
    "composed_from_env_steps",
    "failure_resample_probability",
    "failure_memory_per_env",
];

/// `ppo` keys a resumed run may change: the learning rate and its anneal (which only change the
/// steps to come; a continuation of an annealed run starts where the anneal left the rate).
const RESUMABLE_PPO_CHANGES: [&str; 3] = [
    "learning_rate",
    "learning_rate_final",
    "anneal_start_env_steps",
];

/// How many `extends` a config may chain: more is a cycle or a mistake.
const MAX_EXTENDS: usize = 8;

/// Keys of experiments that measured no gain and left the code (docs/results.md, "Experiments
/// that measured no gain"), with the value that kept each off (`None`: a parameter of the
/// experiment, meaningless without it). Configs and checkpoints written while they existed
/// still load: a retired key holding its off value is dropped, one that would switch the
/// experiment on is an error naming it.
const RETIRED_KEYS: [(&str, &str, Option<RetiredOff>); 4] = [
    (
        "curriculum",
        "planner_demonstrations",
        Some(RetiredOff::Integer(0)),
    ),
    ("curriculum", "planner_demo_expansions", None),
    ("curriculum", "planner_demo_target_beside_only", None),
    (
        "curriculum",
        "replay_planner_share",
        Some(RetiredOff::Float(0.0)),
    ),
];

/// The value that kept a retired experiment off.
#[derive(Clone, Copy)]
enum RetiredOff {
    Integer(i64),
    Float(f64),
}

/// Drops the retired keys from a config's table, or names one that would switch a removed
/// experiment on.
fn drop_retired(table: &mut toml::Table) -> Result<(), ConfigError> {
    for (section, key, off) in RETIRED_KEYS {
        let Some(toml::Value::Table(keys)) = table.get_mut(section) else {
            continue;
        };
        let Some(value) = keys.remove(key) else {
            continue;
        };
        let is_off = match (off, &value) {
            (None, _) => true,
            (Some(RetiredOff::Integer(off)), toml::Value::Integer(v)) => *v == off,
            (Some(RetiredOff::Float(off)), toml::Value::Float(v)) => *v == off,
            (Some(RetiredOff::Float(off)), toml::Value::Integer(v)) => *v as f64 == off,
            _ => false,
        };
        if !is_off {
            return Err(ConfigError::Retired {
                key: format!("{section}.{key}"),
                value: value.to_string(),
            });
        }
    }
    Ok(())
}

/// Parses a config's TOML text into its table, retired keys dropped.
fn parse_table(text: &str) -> Result<toml::Table, ConfigError> {
    let mut table: toml::Table = text
        .parse()
        .map_err(|e: toml::de::Error| ConfigError::Toml(e.to_string()))?;
    drop_retired(&mut table)?;
    Ok(table)
}

/// A config file's keys with its `extends` chain merged beneath them.
fn load_table(path: &Path, depth: usize) -> Result<toml::Table, ConfigError> {
    let text = std::fs::read_to_string(path).map_err(|error| ConfigError::Io {
        path: path.to_path_buf(),
        error,
    })?;
    let mut table = parse_table(&text).map_err(|e| e.in_file(path))?;
    let base = match table.remove("extends") {
        None => return Ok(table),
        Some(toml::Value::String(base)) => base,
        Some(other) => {
            let problem = format!("extends must name a config file, not {other}");
            return Err(ConfigError::Extends(problem).in_file(path));
        }
    };
    if depth >= MAX_EXTENDS {
        let problem = format!("more than {MAX_EXTENDS} configs extend one another (a cycle?)");
        return Err(ConfigError::Extends(problem).in_file(path));
    }
    let base_path = path.parent().unwrap_or(Path::new(".")).join(&base);
    let mut merged = load_table(&base_path, depth + 1).map_err(|error| ConfigError::Base {
        path: path.to_path_buf(),
        base: base.clone(),
        error: Box::new(error),
    })?;
    merge_over(&mut merged, table);
    Ok(merged)
}

/// `over`'s keys replace `base`'s; tables merge key by key.
fn merge_over(base: &mut toml::Table, over: toml::Table) {
    for (key, value) in over {
        match (base.get_mut(&key), value) {
            (Some(toml::Value::Table(below)), toml::Value::Table(above)) => {
                merge_over(below, above)
            }
            (_, value) => {
                base.insert(key, value);
            }
        }
    }
}

impl TrainConfig {
    /// Parses TOML text and validates it.
    pub fn from_toml(text: &str) -> Result<TrainConfig, ConfigError> {
        let config: TrainConfig = toml::Value::Table(parse_table(text)?)
            .try_into()
            .map_err(|e: toml::de::Error| ConfigError::Toml(e.to_string()))?;
        config.validate()?;
        Ok(config)
    }

    /// Reads and validates a config file. A file may start from another: `extends =
    /// "base.toml"` (a path relative to the file's folder) takes every key of the base, and
    /// the file's own keys replace the base's one by one, so a variant names only what it
    /// changes.
    pub fn load(path: &Path) -> Result<TrainConfig, ConfigError> {
        let table = load_table(path, 0)?;
        let mut config: TrainConfig = toml::Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| ConfigError::Toml(e.to_string()).in_file(path))?;
        config.validate().map_err(|e| e.in_file(path))?;
        if !config.run.robot.is_empty() {
            let folder = path.parent().unwrap_or(Path::new(""));
            config.robot = RobotDescription::load(&folder.join(&config.run.robot))
                .map_err(|e| ConfigError::Robot(format!("run.robot: {e}")).in_file(path))?;
        }
        config
            .simulated_robot()
            .map_err(|e| ConfigError::Robot(format!("run.robot: {e}")).in_file(path))?;
        Ok(config)
    }

    /// Trains for the robot described in `path` (`wheelleg train --robot FILE`), in place of
    /// the config's `run.robot`.
    pub fn set_robot(&mut self, path: &Path) -> Result<(), ConfigError> {
        let robot = RobotDescription::load(path).map_err(|e| ConfigError::Robot(e.to_string()))?;
        wheelleg_sim::robot::SimulatedRobot::of(&robot).map_err(ConfigError::Robot)?;
        self.run.robot = path.display().to_string();
        self.robot = robot;
        Ok(())
    }

    /// The config as TOML (stored in every checkpoint to detect mismatched resumes).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).unwrap_or_default()
    }

    /// What a resume from a checkpoint written with `stored` (its config text) would change:
    /// one `"section.key: then -> now"` line per differing key, empty when the run may resume.
    /// Compared parsed, so that a checkpoint written before a key existed still matches when
    /// the key holds its default.
    ///
    /// Compared: `[run]` (except `run.total_env_steps`: extending a finished run is what
    /// resuming is for, and the failure re-sampling keys), `[ppo]`, `[network]`, and of `[curriculum]` only `curriculum_keys`.
    /// The rest of the curriculum describes the pipeline around a stage, and `wheelleg train
    /// all` copies what a stage uses of it into that stage's `run` and `ppo`, so tuning a later
    /// stage does not lock out the finished earlier ones; a stage that reads curriculum keys
    /// directly (the primary's replay) names them.
    pub fn changes_from_stored(
        &self,
        stored: &str,
        curriculum_keys: &[&str],
    ) -> Result<Vec<String>, ConfigError> {
        let then: TrainConfig = parse_table(stored)
            .and_then(|t| {
                toml::Value::Table(t)
                    .try_into()
                    .map_err(|e: toml::de::Error| ConfigError::Toml(e.to_string()))
            })
            .map_err(|e| ConfigError::Stored(format!("stored config does not parse: {e}")))?;
        let as_table = |c: &TrainConfig| {
            toml::Table::try_from(c)
                .map_err(|e| ConfigError::Stored(format!("config does not serialize: {e}")))
        };
        let (then, now) = (as_table(&then)?, as_table(self)?);
        let mut keys: Vec<(&str, String)> = Vec::new();
        for section in ["run", "ppo", "network"] {
            let both = [&then, &now];
            let names = both
                .iter()
                .filter_map(|t| t.get(section).and_then(toml::Value::as_table))
                .flat_map(|t| t.keys().cloned())
                .filter(|k| !(section == "run" && RESUMABLE_CHANGES.contains(&k.as_str())))
                .filter(|k| !(section == "ppo" && RESUMABLE_PPO_CHANGES.contains(&k.as_str())));
            keys.extend(names.map(|k| (section, k)));
        }
        keys.extend(
            curriculum_keys
                .iter()
                .map(|k| ("curriculum", k.to_string())),
        );
        keys.sort();
        keys.dedup();
        let value = |t: &toml::Table, section: &str, key: &str| {
            t.get(section)
                .and_then(toml::Value::as_table)
                .and_then(|s| s.get(key))
                .map_or_else(|| "(none)".to_string(), toml::Value::to_string)
        };
        Ok(keys
            .into_iter()
            .filter_map(|(section, key)| {
                let (a, b) = (value(&then, section, &key), value(&now, section, &key));
                (a != b).then(|| format!("{section}.{key}: {a} -> {b}"))
            })
            .collect())
    }
}
