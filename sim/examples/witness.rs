//! Probe: scripted plans through fence scenes.
use rand::SeedableRng;
use wheelleg_runtime::action::{Action, Step};
use wheelleg_sim::env::{Env, EnvConfig};
use wheelleg_sim::generate::{generate_many, Behaviour, SceneKind};
fn main() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let args: Vec<String> = std::env::args().collect();
    let kind = SceneKind::from_name(&args[1]).unwrap();
    let dc: i32 = args[2].parse().unwrap();
    let dt: i32 = args[3].parse().unwrap();
    for s in generate_many(kind, &mut rng, 6) {
        let mut env = Env::new(
            &s,
            EnvConfig {
                max_steps: 200,
                ..Default::default()
            },
        )
        .unwrap();
        let opening_y = s
            .obstacles
            .iter()
            .find(|o| {
                matches!(
                    (kind, o.kind),
                    (
                        SceneKind::Behaviour(Behaviour::SpreadOver),
                        wheelleg_sim::obstacle::ObstacleKind::Slab
                    )
                )
            })
            .map(|o| o.centre.y)
            .unwrap_or_else(|| {
                // squeeze: the missing cell; lift: nearest bar
                if kind == SceneKind::Behaviour(Behaviour::Squeeze) {
                    let ys: Vec<f32> = s.obstacles.iter().map(|o| o.centre.y).collect();
                    let mut y = ys[0];
                    while ys.iter().any(|v| (v - y).abs() < 1e-3) {
                        y += 0.25;
                    }
                    y
                } else {
                    s.obstacles
                        .iter()
                        .map(|o| o.centre.y)
                        .min_by(|a, b| {
                            (a - s.start.position.y)
                                .abs()
                                .total_cmp(&(b - s.start.position.y).abs())
                        })
                        .unwrap()
                }
            });
        let mut log = String::new();
        let mut go = |env: &mut Env, a: Action, log: &mut String| {
            if let Ok(o) = env.step(a) {
                if let Some(i) = o.invalid {
                    log.push_str(&format!("{i:?}@{} ", env.steps()));
                }
            }
        };
        // rotate to 0
        let mut yaw = env.state().yaw_steps;
        while yaw != 0 {
            let a = Action {
                yaw: if yaw > 36 { Step::Plus } else { Step::Minus },
                ..Action::IDLE
            };
            go(&mut env, a, &mut log);
            yaw = env.state().yaw_steps;
            if env.steps() > 60 {
                break;
            }
        }
        for _ in 0..dc.abs().max(dt.abs()) {
            let a = Action {
                clearance: if env.state().clearance_steps == dc {
                    Step::Zero
                } else if dc > 0 {
                    Step::Plus
                } else {
                    Step::Minus
                },
                track: if env.state().track_steps == dt {
                    Step::Zero
                } else if dt > 0 {
                    Step::Plus
                } else {
                    Step::Minus
                },
                ..Action::IDLE
            };
            go(&mut env, a, &mut log);
        }
        for _ in 0..20 {
            let dy = opening_y - env.state().position.y;
            if dy.abs() < 0.03 {
                break;
            }
            go(
                &mut env,
                Action {
                    move_y: if dy > 0.0 { Step::Plus } else { Step::Minus },
                    ..Action::IDLE
                },
                &mut log,
            );
        }
        for _ in 0..40 {
            if env.status().is_done() {
                break;
            }
            let dx = s.target.x - env.state().position.x;
            let dy = s.target.y - env.state().position.y;
            let a = Action {
                move_x: if dx > 0.03 {
                    Step::Plus
                } else if dx < -0.03 {
                    Step::Minus
                } else {
                    Step::Zero
                },
                move_y: if dx < 0.1 && dy.abs() > 0.03 {
                    if dy > 0.0 {
                        Step::Plus
                    } else {
                        Step::Minus
                    }
                } else {
                    Step::Zero
                },
                ..Action::IDLE
            };
            go(&mut env, a, &mut log);
        }
        println!(
            "{} opening {:.3} start y {:.3} -> {:?} steps {} pos {:?} {}",
            s.name,
            opening_y,
            s.start.position.y,
            env.status(),
            env.steps(),
            env.state().position,
            log
        );
    }
}
