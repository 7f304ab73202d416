//! The batch in memory: its sources and scenes, loaded strictly, and the trajectories drawn
//! from it.

use super::*;

/// One source trajectory as held in memory.
#[derive(Clone, Debug, PartialEq)]
pub struct StoredSource {
    /// The source scenario's name.
    pub name: String,
    /// The behaviour whose secondary policy produced it.
    pub behaviour: Behaviour,
    /// Start.
    pub start: RobotState,
    /// Target.
    pub target: Point2<f32>,
    /// The actions (undone actions removed).
    pub actions: Vec<Action>,
    /// Obstacles in every scene of this source.
    pub kept: Vec<Obstacle>,
    /// Scenes tried.
    pub tried: u32,
    /// Scenes kept.
    pub scenes: u32,
    /// Whether the first scene is the source's own.
    pub original_included: bool,
    /// Why it was not randomized (empty when it was).
    pub rejected: String,
    /// Index of its first scene in the batch.
    pub first_scene: u32,
}

/// One scene in memory: 12 bytes plus 6 per new obstacle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct SceneRef {
    source: u32,
    first_obstacle: u32,
    obstacles: u16,
}

/// A whole batch in memory, compactly: sources once, scenes as references plus their new
/// obstacles. [`TrajectoryBatch::trajectory`] materializes one trajectory.
#[derive(Clone, Debug)]
pub struct TrajectoryBatch {
    header: BatchHeader,
    sources: Vec<StoredSource>,
    scenes: Vec<SceneRef>,
    obstacles: Vec<PackedObstacle>,
    file_bytes: u64,
}

impl TrajectoryBatch {
    /// Reads and checks a complete batch file.
    pub fn load(path: &Path) -> Result<TrajectoryBatch, BatchFileError> {
        let bytes = fs::read(path).map_err(|e| io_error(path, e))?;
        TrajectoryBatch::from_bytes(&bytes)
    }

    /// Decodes and checks the bytes of a complete batch file.
    pub fn from_bytes(bytes: &[u8]) -> Result<TrajectoryBatch, BatchFileError> {
        let (header, start) = parse_header(bytes)?;
        let scan = scan_chunks(bytes, &header, start);
        if let Some(problem) = scan.problem {
            return Err(problem);
        }
        if scan.sources_done != header.sources {
            return Err(BatchFileError::Incomplete {
                sources_done: scan.sources_done,
                sources_total: header.sources,
            });
        }
        let mut batch = TrajectoryBatch {
            header,
            sources: Vec::new(),
            scenes: Vec::new(),
            obstacles: Vec::new(),
            file_bytes: bytes.len() as u64,
        };
        let lattice = *batch.header.simulated_robot()?.lattice();
        for chunk in scan.chunks {
            for record in chunk.sources {
                batch.push_source(record, &lattice)?;
            }
        }
        // Millions of scenes: the growth slack of the vectors would be a third of the memory.
        batch.scenes.shrink_to_fit();
        batch.obstacles.shrink_to_fit();
        Ok(batch)
    }

    /// Adds a checked source, its start counted on `lattice` (the batch's robot's).
    fn push_source(
        &mut self,
        record: SourceRecord,
        lattice: &ActionLattice,
    ) -> Result<(), BatchFileError> {
        let too_big = || BatchFileError::Unstorable {
            reason: "more than 2^32 scenes or obstacles in memory".into(),
        };
        let source = u32::try_from(self.sources.len()).map_err(|_| too_big())?;
        let first_scene = u32::try_from(self.scenes.len()).map_err(|_| too_big())?;
        for scene in &record.scenes {
            self.scenes.push(SceneRef {
                source,
                first_obstacle: u32::try_from(self.obstacles.len()).map_err(|_| too_big())?,
                obstacles: scene.len() as u16,
            });
            self.obstacles.extend_from_slice(scene);
        }
        // Chunks were checked: every code and action index decodes.
        self.sources.push(StoredSource {
            name: record.name.clone(),
            behaviour: behaviour_of_code(record.behaviour).unwrap_or(Behaviour::Straight),
            start: record.start_state(lattice),
            target: Point2::new(record.target_x_m, record.target_y_m),
            actions: record
                .actions
                .iter()
                .filter_map(|&a| Action::from_index(a as usize))
                .collect(),
            kept: record
                .kept
                .iter()
                .filter_map(PackedObstacle::unpack)
                .collect(),
            tried: record.tried,
            scenes: record.scenes.len() as u32,
            original_included: record.original_included,
            rejected: record.rejected,
            first_scene,
        });
        Ok(())
    }

    /// Adds every trajectory of `other` after this batch's own, so that one replay draws from
    /// both (the secondaries' batch and expert labels, say). The header stays this batch's:
    /// refused, naming what differs, when the two batches replay under other episode rules or
    /// were driven by another robot, since a trajectory holds only under its own.
    pub fn append(&mut self, other: TrajectoryBatch) -> Result<(), TrainError> {
        let (ours, theirs) = (self.env_config()?, other.env_config()?);
        if theirs != ours {
            return Err(TrainError::Incompatible(format!(
                "the batches replay under different episode rules ({ours:?} and {theirs:?})"
            )));
        }
        if other.header.robot != self.header.robot {
            return Err(TrainError::Incompatible(format!(
                "the batches hold trajectories of different robots ('{}' and '{}')",
                self.header.robot().name,
                other.header.robot().name
            )));
        }
        let offset = |len: usize| {
            u32::try_from(len).map_err(|_| {
                TrainError::Incompatible("more than 2^32 scenes or obstacles in memory".into())
            })
        };
        let (sources, scenes, obstacles) = (
            offset(self.sources.len())?,
            offset(self.scenes.len())?,
            offset(self.obstacles.len())?,
        );
        offset(self.scenes.len() + other.scenes.len())?;
        offset(self.obstacles.len() + other.obstacles.len())?;
        offset(self.sources.len() + other.sources.len())?;
        self.scenes.extend(other.scenes.iter().map(|s| SceneRef {
            source: s.source + sources,
            first_obstacle: s.first_obstacle + obstacles,
            obstacles: s.obstacles,
        }));
        self.sources
            .extend(other.sources.into_iter().map(|s| StoredSource {
                first_scene: s.first_scene + scenes,
                ..s
            }));
        self.obstacles.extend_from_slice(&other.obstacles);
        self.file_bytes += other.file_bytes;
        Ok(())
    }

    /// The header (parameters and episode rules).
    pub fn header(&self) -> &BatchHeader {
        &self.header
    }

    /// The episode rules every stored trajectory replays under.
    pub fn env_config(&self) -> Result<EnvConfig, BatchFileError> {
        self.header.env_config()
    }

    /// Number of stored trajectories (scenes).
    pub fn len(&self) -> usize {
        self.scenes.len()
    }

    /// Whether no trajectory is stored.
    pub fn is_empty(&self) -> bool {
        self.scenes.is_empty()
    }

    /// The source trajectories.
    pub fn sources(&self) -> &[StoredSource] {
        &self.sources
    }

    /// The source of trajectory `index`.
    pub fn source_of(&self, index: usize) -> Option<&StoredSource> {
        self.scenes
            .get(index)
            .map(|scene| &self.sources[scene.source as usize])
    }

    /// Trajectory `index`: its scene is the source's start, target and kept obstacles plus the
    /// scene's new obstacles; its actions are the source's. `None` past the end.
    pub fn trajectory(&self, index: usize) -> Option<Trajectory> {
        let scene = self.scenes.get(index)?;
        let source = &self.sources[scene.source as usize];
        let first = scene.first_obstacle as usize;
        let new = &self.obstacles[first..first + scene.obstacles as usize];
        let mut obstacles = source.kept.clone();
        obstacles.extend(new.iter().filter_map(PackedObstacle::unpack));
        let k = index - source.first_scene as usize;
        let name = if source.original_included && k == 0 {
            source.name.clone()
        } else {
            format!("{}-r{k}", source.name)
        };
        Some(Trajectory {
            scenario: Scenario {
                name,
                start: source.start,
                target: source.target,
                obstacles,
            },
            actions: source.actions.clone(),
            behaviour: source.behaviour,
        })
    }

    /// Stored trajectories per behaviour, in [`Behaviour::ALL`] order.
    pub fn counts_by_behaviour(&self) -> [usize; Behaviour::ALL.len()] {
        let mut counts = [0; Behaviour::ALL.len()];
        for s in &self.sources {
            counts[behaviour_code(s.behaviour) as usize] += s.scenes as usize;
        }
        counts
    }

    /// Size of the file it was read from.
    pub fn file_bytes(&self) -> u64 {
        self.file_bytes
    }

    /// Approximate heap bytes held (scenes, obstacles, sources with their actions).
    pub fn memory_bytes(&self) -> usize {
        self.scenes.capacity() * std::mem::size_of::<SceneRef>()
            + self.obstacles.capacity() * std::mem::size_of::<PackedObstacle>()
            + self
                .sources
                .iter()
                .map(|s| {
                    std::mem::size_of::<StoredSource>()
                        + s.name.capacity()
                        + s.actions.capacity() * std::mem::size_of::<Action>()
                        + s.kept.capacity() * std::mem::size_of::<Obstacle>()
                        + s.rejected.capacity()
                })
                .sum::<usize>()
    }
}
