//! Could the collisions of log-replay runs have been avoided, and from which step? Runs each
//! given (scene, seed) in the log-replay world on the shipped defaults, then, for every
//! collision event (at fault only, unless `--all`), asks the oracle of
//! `nudge_research::oracle` from the ego's recorded state before each of the last
//! `--look-back` steps up to the contact: is there any sequence of inputs within the planner's
//! bounds that meets nobody, keeps the road and the heading bound until `--after` steps past
//! the contact? Prints one markdown row per event.
//!
//! ```text
//! cargo run --release -p nudge-research --bin avoidability -- [--planner student|teacher]
//!     [--look-back 10] [--after 2] [--hold 2] [--max-nodes 2000000] [--all] PATH:SEED...
//! ```
//!
//! Columns: the contact step c; the other vehicle; whether the ego is at fault (the project's
//! rule, then nuPlan's); the latest step k ≤ c from whose state it was avoidable and the
//! time from that decision to the contact, (c − k + 1) · dt; the oracle's answer at each step
//! from c − look-back to c (A avoidable, U unavoidable, ? undecided); the planner's status at
//! steps k..=c; and the other vehicle's lateral speed towards the ego at step k (m/s, from its
//! logged displacement).
#![allow(clippy::print_stdout, clippy::print_stderr)]

use std::path::PathBuf;

use clap::Parser;
use nudge_planner::{PlannerSettings, Scenario};
use nudge_predictor::{PredictorSpec, T_OBS, default_assets_dir};
use nudge_research::oracle::{
    Avoidance, LoggedTraffic, OracleLimits, OracleStart, OracleWorld, avoid, replay,
};
use nudge_sim::metrics::RunObserver;
use nudge_sim::{SimConfig, World, WorldModel, simulate};

#[derive(Parser, Debug)]
#[command(about = "Were log-replay collisions avoidable, and from when?")]
struct Args {
    /// Planning predictor, by name under the assets directory or by path.
    #[arg(long, default_value = "student")]
    planner: String,
    /// Steps before the contact to ask from.
    #[arg(long, default_value_t = 10)]
    look_back: usize,
    /// Steps past the contact the ego must stay clear.
    #[arg(long, default_value_t = 2)]
    after: usize,
    /// Steps each lattice choice is held.
    #[arg(long, default_value_t = OracleLimits::DEFAULT_HOLD)]
    hold: usize,
    /// Lattice blocks per search before it gives up.
    #[arg(long, default_value_t = OracleLimits::DEFAULT_MAX_NODES)]
    max_nodes: usize,
    /// Every collision event, not only those at fault.
    #[arg(long)]
    all: bool,
    /// Runs as SCENE_PATH:SEED.
    #[arg(required = true)]
    runs: Vec<String>,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = Args::parse();
    let assets = default_assets_dir();
    let settings = PlannerSettings::default();
    let cfg = SimConfig {
        world: World::LogReplay,
        ..SimConfig::default()
    };
    let mut predictor =
        PredictorSpec::resolve(&args.planner, &assets, settings.model.horizon)?.build();
    let mut limits = OracleLimits::of(&settings);
    limits.hold = args.hold;
    limits.max_nodes = args.max_nodes;
    println!(
        "| scene | seed | c | other (id) | at fault (nuPlan) | latest avoidable k | lead s | oracle c−{}..c | constant velocity known | planner k..c | other's lateral speed towards the ego m/s |",
        args.look_back
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for spec in &args.runs {
        let (path, seed) = spec
            .rsplit_once(':')
            .ok_or_else(|| format!("{spec}: expected SCENE_PATH:SEED"))?;
        let seed: u64 = seed.parse().map_err(|e| format!("{spec}: seed: {e}"))?;
        let sc = Scenario::from_file(PathBuf::from(path))?;
        let run = simulate(
            &sc,
            &settings,
            &cfg,
            seed,
            predictor.as_mut(),
            WorldModel::LogReplay,
        )?;
        let traffic = LoggedTraffic::new(&sc, cfg.max_steps, cfg.replay_lateral_decay);
        let observer = RunObserver::new(
            &sc,
            run.target_lane,
            cfg.fault_brake_limit,
            settings.model.l_r,
        );
        let world = OracleWorld {
            bicycle: nudge_planner::Bicycle {
                l_f: settings.model.l_f,
                l_r: settings.model.l_r,
                dt: settings.model.dt,
            },
            size: sc.size[0],
            bounds: &sc.lane_bounds,
            road_tolerance: observer.off_road_tolerance(),
            traffic: &traffic,
        };
        let p0 = sc.position(0, T_OBS - 1);
        let start_of = |k: usize| {
            if k == 0 {
                OracleStart {
                    step: 0,
                    ego: [p0[0], p0[1], sc.heading[0], sc.speed[0]],
                    inputs: (0.0, 0.0),
                }
            } else {
                let s = &run.steps[k - 1];
                OracleStart {
                    step: k,
                    ego: s.ego,
                    inputs: (s.delta, s.accel),
                }
            }
        };
        for ev in run.collisions.iter().filter(|e| args.all || e.at_fault) {
            let c = ev.step;
            let until = (c + args.after).min(cfg.max_steps - 1);
            let from = c.saturating_sub(args.look_back);
            let mut marks = String::new();
            let mut cv_marks = String::new();
            let mut latest = None;
            for k in from..=c {
                let found = avoid(&world, &limits, &start_of(k), until);
                marks.push(match found {
                    Avoidance::Avoidable(_) => {
                        latest = Some(k);
                        'A'
                    }
                    Avoidance::Unavoidable { .. } => 'U',
                    Avoidance::Undecided { .. } => '?',
                });
                let guess = traffic.extrapolated(&sc, k);
                let known = OracleWorld {
                    traffic: &guess,
                    ..world
                };
                cv_marks.push(match avoid(&known, &limits, &start_of(k), until) {
                    Avoidance::Avoidable(inputs) => {
                        match replay(&world, &limits, &start_of(k), &inputs).1 {
                            None => 'C',
                            Some(_) => 'c',
                        }
                    }
                    Avoidance::Unavoidable { .. } => 'u',
                    Avoidance::Undecided { .. } => '?',
                });
            }
            let statuses = |k: usize| {
                run.steps[k..=c]
                    .iter()
                    .map(|s| s.status.as_str())
                    .collect::<Vec<_>>()
                    .join(" ")
            };
            let lateral = |k: usize| {
                let i = ev.other - 1;
                let now = traffic.steps.get(k.max(1) - 1).map(|o| o[i].bbox.y);
                let before = k
                    .checked_sub(2)
                    .and_then(|j| traffic.steps.get(j))
                    .map(|o| o[i].bbox.y);
                let before = before.or_else(|| Some(sc.position(ev.other, T_OBS - 1)[1]));
                let ego_y = start_of(k).ego[1];
                match (now, before) {
                    (Some(a), Some(b)) => ((a - b) / settings.model.dt) * (ego_y - a).signum(),
                    _ => f64::NAN,
                }
            };
            let (k_txt, lead, st, lat) = match latest {
                Some(k) => (
                    k.to_string(),
                    format!("{:.1}", (c - k + 1) as f64 * settings.model.dt),
                    statuses(k),
                    format!("{:+.2}", lateral(k)),
                ),
                None => (
                    format!("< {from}"),
                    format!("> {:.1}", (c - from + 1) as f64 * settings.model.dt),
                    statuses(from),
                    format!("{:+.2}", lateral(from)),
                ),
            };
            println!(
                "| {} | {seed} | {c} | {} ({}) | {} ({}) | {k_txt} | {lead} | {marks} | {cv_marks} | {st} | {lat} |",
                sc.name,
                ev.other,
                sc.agent_ids[ev.other],
                if ev.at_fault { "yes" } else { "no" },
                if ev.nuplan_at_fault { "yes" } else { "no" },
            );
        }
    }
    Ok(())
}
