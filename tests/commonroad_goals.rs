//! Goal regions and the curvilinear road frame of the CommonRoad reader, against the files
//! themselves: goal states read as the files write them (numbers copied from the XML), goals
//! the planner cannot aim at refused with a typed error naming the problem, and the
//! curvilinear frame's round trip (file → road → file) on real curved scenes, whose lanes it
//! makes straight where the straightened frame leaves them bent by metres.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use nudge::commonroad::scene::{NEIGHBOUR_RANGE, STRAIGHT_HALF_RANGE, STRAIGHT_TOL};
use nudge::commonroad::{CommonRoadError, CommonRoadScene, Ego, GoalShape, Interval};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn fixture(name: &str) -> PathBuf {
    repo()
        .join("python/train/tests/fixtures/commonroad")
        .join(name)
}

fn shared(name: &str) -> PathBuf {
    let root = std::env::var_os("NUDGE_NGSIM")
        .filter(|v| !v.is_empty())
        .map_or_else(|| repo().join("../shared/data/ngsim"), PathBuf::from);
    root.join("us101/commonroad_us101_T-1").join(name)
}

fn gunzip(path: &Path) -> String {
    let mut s = String::new();
    flate2::read::GzDecoder::new(std::fs::File::open(path).unwrap())
        .read_to_string(&mut s)
        .unwrap();
    s
}

fn write_xml(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::File::create(&p)
        .unwrap()
        .write_all(text.as_bytes())
        .unwrap();
    p
}

fn tmp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("nudge-cr-goals-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// USA_US101-26_1 planning problem 33: a rectangle, orientation, time and velocity intervals,
/// exactly as the file writes them.
#[test]
fn rectangle_goal_is_read_as_written() {
    let path = shared("USA_US101-26_1_T-1.xml.gz");
    let scene = CommonRoadScene::read(&path).unwrap();
    let pp = scene
        .raw
        .planning_problems
        .iter()
        .find(|p| p.id == 33)
        .unwrap();
    assert_eq!(pp.goals.len(), 1);
    let g = &pp.goals[0];
    assert_eq!(g.time, Interval { lo: 70.0, hi: 80.0 });
    assert_eq!(
        g.velocity,
        Some(Interval {
            lo: 7.668,
            hi: 13.668
        })
    );
    assert_eq!(
        g.orientation,
        Some(Interval {
            lo: -0.81142,
            hi: -0.63688
        })
    );
    assert_eq!(
        g.shapes,
        vec![GoalShape::Rectangle {
            length: 2.4059,
            width: 1.8507,
            orientation: -0.72723,
            center: [65.7533, -52.9096],
        }]
    );
    // The checker's test: the centre at step 75 with a speed and heading inside is reached;
    // a step, a speed or a heading outside, or a point 1.3 m along, is not.
    let c = [65.7533, -52.9096];
    assert!(g.reached_by(75, c, 10.0, -0.7));
    assert!(!g.reached_by(81, c, 10.0, -0.7));
    assert!(!g.reached_by(75, c, 14.0, -0.7));
    assert!(!g.reached_by(75, c, 10.0, -0.5));
    let (s, co) = (-0.72723f64).sin_cos();
    assert!(!g.reached_by(75, [c[0] + 1.3 * co, c[1] + 1.3 * s], 10.0, -0.7));
    assert!(g.reached_by(75, [c[0] + 1.1 * co, c[1] + 1.1 * s], 10.0, -0.7));
}

/// USA_US101-1_1 planning problem 482 aims at lanelet 534: the goal's shape is that lanelet's
/// outline, and it maps to one lane of the road frame ahead of the ego.
#[test]
fn lanelet_goal_is_its_outline_and_one_lane() {
    let path = fixture("USA_US101-1_1_T-1.xml.gz");
    let scene = CommonRoadScene::read(&path).unwrap();
    let pp = &scene.raw.planning_problems[0];
    let g = &pp.goals[0];
    assert_eq!(g.time, Interval { lo: 45.0, hi: 75.0 });
    let GoalShape::Lanelet { id, outline } = &g.shapes[0] else {
        panic!("{:?}", g.shapes[0]);
    };
    assert_eq!(id, "534");
    let ll = scene.raw.lanelets.iter().find(|l| l.id == "534").unwrap();
    assert_eq!(outline.len(), ll.left.len() + ll.right.len());
    let mid = [
        0.5 * (ll.left[1][0] + ll.right[ll.right.len() - 2][0]),
        0.5 * (ll.left[1][1] + ll.right[ll.right.len() - 2][1]),
    ];
    assert!(g.shapes[0].contains(mid));
    let ego = Ego::PlanningProblem(pp.id);
    let t0 = scene.default_t0(ego).unwrap();
    let sc = scene.scenario(ego, t0).unwrap();
    let goal = scene.road_goal(pp.id, t0, sc.position(0, 7)).unwrap();
    let b = scene.lanes.bounds_at(0.5 * (goal.x[0] + goal.x[1]));
    assert!(b[goal.lane] <= goal.y && goal.y <= b[goal.lane + 1]);
    assert!((goal.time_s[0] - 4.5).abs() < 1e-9 && (goal.time_s[1] - 7.5).abs() < 1e-9);
}

/// A goal moved 5 km away, one behind the ego, and one whose window has passed: each a
/// [`CommonRoadError::Goal`] naming the problem and the reason.
#[test]
fn goals_the_planner_cannot_aim_at_are_typed_errors() {
    let text = gunzip(&shared("USA_US101-26_1_T-1.xml.gz"));
    let dir = tmp_dir("refuse");
    let cases = [
        ("<x>65.7533</x>", "<x>5065.7533</x>", "beyond the map"),
        (
            "<x>65.7533</x><y>-52.9096</y>",
            "<x>-40.0</x><y>33.0</y>",
            "behind the ego",
        ),
        (
            "<intervalStart>70</intervalStart>\n        <intervalEnd>80</intervalEnd>",
            "<intervalStart>0</intervalStart>\n        <intervalEnd>0</intervalEnd>",
            "ends before t0",
        ),
    ];
    let compact = text.replace(
        "<x>65.7533</x>\n            <y>-52.9096</y>",
        "<x>65.7533</x><y>-52.9096</y>",
    );
    for (k, (from, to, want)) in cases.iter().enumerate() {
        assert!(compact.contains(from), "case {k}: {from} not in the file");
        let p = write_xml(
            &dir,
            &format!("case{k}.xml"),
            &compact.replacen(from, to, 1),
        );
        let scene = CommonRoadScene::read(&p).unwrap();
        let err = scene.road_goal(33, 0.0, [0.0, 0.0]).unwrap_err();
        let msg = err.to_string();
        assert!(
            matches!(err, CommonRoadError::Goal { problem: 33, .. }) && msg.contains(want),
            "case {k}: {msg}"
        );
    }
    std::fs::remove_dir_all(dir).ok();
}

/// A goal state without <time> is a field error naming the element.
#[test]
fn goal_without_time_is_a_field_error() {
    let text = gunzip(&fixture("USA_US101-1_1_T-1.xml.gz"));
    let start = text.rfind("<time>").unwrap();
    let end = text.rfind("</time>").unwrap() + "</time>".len();
    let dir = tmp_dir("notime");
    let p = write_xml(
        &dir,
        "notime.xml",
        &format!("{}{}", &text[..start], &text[end..]),
    );
    let err = CommonRoadScene::read(&p).unwrap_err();
    assert!(
        matches!(&err, CommonRoadError::Field { element, .. } if element.contains("goal state 1 time")),
        "{err}"
    );
    std::fs::remove_dir_all(dir).ok();
}

/// The curved fixture (USA_US101-26_1, cut): in the curvilinear frame every lanelet point and
/// every vehicle state maps to the road and back onto the file's own coordinates within 1 µm
/// (headings within 1 µrad), and the lanes near every vehicle are straight within the
/// planner's tolerance, where the straightened frame leaves them bent by more.
#[test]
fn curvilinear_frame_round_trips_and_straightens_a_curved_scene() {
    let path = fixture("USA_US101-26_1_T-1_cut.xml.gz");
    let straight = CommonRoadScene::read(&path).unwrap();
    let curved = straight.curvilinear().unwrap();
    assert!(curved.frame.is_curvilinear() && !straight.frame.is_curvilinear());
    let mut worst: f64 = 0.0;
    let mut worst_h: f64 = 0.0;
    let pts = curved
        .raw
        .lanelets
        .iter()
        .flat_map(|l| l.left.iter().chain(&l.right).map(|&p| (p, None)))
        .chain(
            curved
                .raw
                .obstacles
                .iter()
                .flat_map(|o| o.states.iter().map(|s| ([s.x, s.y], Some(s.orientation)))),
        );
    let mut n = 0;
    for (p, o) in pts {
        let r = curved.frame.to_road(p);
        let back = curved.frame.try_to_file(r).unwrap();
        worst = worst.max((back[0] - p[0]).hypot(back[1] - p[1]));
        if let Some(o) = o {
            let h = curved.frame.heading_to_road(p, o);
            let d = nudge::commonroad::frame::wrap_angle(curved.frame.heading_to_file(r, h) - o);
            worst_h = worst_h.max(d.abs());
        }
        n += 1;
    }
    assert!(n > 1000 && worst < 1e-6, "{n} points, worst {worst} m");
    assert!(worst_h < 1e-6, "worst heading {worst_h} rad");
    // Lanes near each vehicle's first state, in both frames.
    let (mut bent_straight, mut bent_curved): (f64, f64) = (0.0, 0.0);
    for t in &curved.tracks {
        let x = t.states[0].pos[0];
        bent_curved = bent_curved.max(curved.lanes.local_deviation(x, STRAIGHT_HALF_RANGE));
    }
    for t in &straight.tracks {
        let x = t.states[0].pos[0];
        bent_straight = bent_straight.max(straight.lanes.local_deviation(x, STRAIGHT_HALF_RANGE));
    }
    assert!(bent_curved <= STRAIGHT_TOL, "curvilinear: {bent_curved} m");
    assert!(
        bent_straight > 2.0 * STRAIGHT_TOL,
        "straightened: {bent_straight} m"
    );
}

/// A curved planning problem (USA_US101-26_1, problem 33), refused by the straightened frame
/// for its road shape, is prepared in the curvilinear frame; its ego starts at the problem's
/// initial state mapped through that frame.
#[test]
fn curved_problem_is_prepared_in_the_curvilinear_frame() {
    let path = shared("USA_US101-26_1_T-1.xml.gz");
    let ego = Ego::PlanningProblem(33);
    let straight = CommonRoadScene::read(&path).unwrap();
    let refused = straight
        .scenario_in_range(ego, 0.0, NEIGHBOUR_RANGE)
        .unwrap_err();
    assert!(refused.to_string().contains("road shape"), "{refused}");
    let (scene, t0, sc, _) = CommonRoadScene::prepare(&path, ego, None, NEIGHBOUR_RANGE).unwrap();
    assert!(scene.frame.is_curvilinear());
    assert!(t0.abs() < 1e-12);
    let init = &scene.raw.planning_problems[0].initial;
    let start = scene.frame.to_road([init.x, init.y]);
    let last = sc.position(0, 7);
    assert!((last[0] - start[0]).hypot(last[1] - start[1]) < 1e-9);
    assert!(scene.road_goal(33, t0, last).is_ok());
}

/// USA_US101-18_1, problem 373: the goal lies in the lane an on-ramp adds 18 m ahead of the
/// ego. In the curvilinear frame the scenario carries every lane with its extent
/// ("nudge.scenario/2"): that lane begins inside the scene, ahead of the ego, and the goal's y
/// lies in it.
#[test]
fn a_lane_that_joins_ahead_is_in_the_scenario_with_its_extent() {
    let path = shared("USA_US101-18_1_T-1.xml.gz");
    let ego = Ego::PlanningProblem(373);
    let (scene, t0, sc, _) = CommonRoadScene::prepare(&path, ego, None, NEIGHBOUR_RANGE).unwrap();
    assert!(scene.frame.is_curvilinear());
    assert_eq!(sc.metadata["schema"], nudge::planner::SCHEMA_EXTENTS);
    let ext = sc.lane_extents.as_ref().unwrap();
    let x0 = sc.position(0, 7)[0];
    let goal = scene.road_goal(373, t0, sc.position(0, 7)).unwrap();
    let lane = sc
        .lane_bounds
        .windows(2)
        .position(|w| w[0] <= goal.y && goal.y <= w[1])
        .unwrap();
    assert!(
        ext[lane].begins && ext[lane].begin > x0 + 10.0,
        "{:?} ego x {x0}",
        ext[lane]
    );
    assert!(ext[sc.ego_lane].begin <= x0 && x0 <= ext[sc.ego_lane].end);
    // Without its extents (the lanes at the ego's x only) the goal lane is not on the road.
    let here = scene.lanes.bounds_at(x0);
    assert!(goal.y < here[0], "goal y {} lanes {here:?}", goal.y);
}
