//! The CommonRoad reader against the data pipeline (`nudge_train.data`), which made every
//! shipped scenario: built from the CommonRoad source files, each shipped scene's tensors must
//! equal the pipeline's to 1 mm (positions, lanes) / 1 mrad / 1 mm/s. The road frame's inverse
//! must give back the file's own coordinates. The shared NGSIM folder is
//! `$NUDGE_NGSIM`, else `../shared/data/ngsim` beside the repository (as the pipeline's).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};

use nudge::commonroad::{CommonRoadError, CommonRoadScene, Ego, RawScenario};
use nudge::planner::Scenario;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn ngsim() -> PathBuf {
    std::env::var_os("NUDGE_NGSIM")
        .filter(|v| !v.is_empty())
        .map_or_else(|| repo().join("../shared/data/ngsim"), PathBuf::from)
}

/// The CommonRoad file a shipped scene came from (2020a, else 2018b).
fn source_of(sc: &Scenario) -> PathBuf {
    let name = &sc.metadata["source"];
    let us = ngsim().join("us101");
    let a = us.join("commonroad_us101_T-1").join(name);
    if a.exists() {
        a
    } else {
        us.join("commonroad_us101_2018b_extra").join(name)
    }
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

#[test]
fn shipped_scenes_equal_the_pipelines_to_a_millimetre() {
    let paths = Scenario::paths_in(repo().join("assets/scenes")).unwrap();
    assert_eq!(paths.len(), 10);
    let mut worst: f64 = 0.0;
    for p in &paths {
        let want = Scenario::from_file(p).unwrap();
        let src = source_of(&want);
        assert!(
            src.exists(),
            "{} missing: the shared NGSIM data is needed (set NUDGE_NGSIM)",
            src.display()
        );
        let scene = CommonRoadScene::read(&src).unwrap();
        let t0: f64 = want.metadata["t0_s"].parse().unwrap();
        let prov = &want.metadata["provenance"];
        let range: f64 = prov
            .split("neighbours within ")
            .nth(1)
            .and_then(|r| r.split(' ').next())
            .unwrap()
            .parse()
            .unwrap();
        let got = scene
            .scenario_in_range(Ego::Obstacle(want.agent_ids[0]), t0, range)
            .unwrap()
            .0;
        let name = p.display();
        assert_eq!(got.agent_ids, want.agent_ids, "{name}");
        assert_eq!(got.n_future, want.n_future, "{name}");
        assert_eq!(got.future_valid, want.future_valid, "{name}");
        assert_eq!(got.ego_lane, want.ego_lane, "{name}");
        for (what, a, b, tol) in [
            ("history", &got.history, &want.history, 1e-3),
            ("future", &got.future, &want.future, 1e-3),
            ("lane_bounds", &got.lane_bounds, &want.lane_bounds, 1e-3),
            ("lane_centres", &got.lane_centres, &want.lane_centres, 1e-3),
            ("heading", &got.heading, &want.heading, 1e-3),
            ("speed", &got.speed, &want.speed, 1e-3),
        ] {
            let d = max_abs_diff(a, b);
            assert!(d <= tol, "{name}: {what} differs by {d}");
            worst = worst.max(d);
        }
        let sizes = |s: &Scenario| s.size.iter().flatten().copied().collect::<Vec<f64>>();
        assert!(
            max_abs_diff(&sizes(&got), &sizes(&want)) < 1e-12,
            "{name}: size"
        );
    }
    eprintln!("largest difference from the pipeline over the shipped scenes: {worst:e}");
}

/// Every obstacle state mapped into the road frame and back lands on the file's own
/// coordinates (the inverse of the road-frame transform) within 1 µm and 1 µrad.
#[test]
fn road_frame_inverse_gives_back_the_files_coordinates() {
    let fixture = repo().join("python/train/tests/fixtures/commonroad/USA_US101-1_1_T-1.xml.gz");
    let raw = RawScenario::read(&fixture).unwrap();
    let scene = CommonRoadScene::from_raw(raw.clone()).unwrap();
    let mut n = 0;
    for (o, t) in raw.obstacles.iter().zip(
        raw.obstacles
            .iter()
            .map(|o| scene.tracks.iter().find(|t| t.id == o.id).unwrap()),
    ) {
        for (s, r) in o.states.iter().zip(&t.states) {
            let back = scene.frame.to_file(r.pos);
            assert!(
                (back[0] - s.x).hypot(back[1] - s.y) < 1e-6,
                "obstacle {} step {}",
                o.id,
                s.step
            );
            let h = scene.frame.heading_to_file(r.pos, r.heading);
            let dh = nudge::commonroad::frame::wrap_angle(h - s.orientation);
            assert!(
                dh.abs() < 1e-6,
                "obstacle {} step {} heading off by {dh}",
                o.id,
                s.step
            );
            n += 1;
        }
    }
    assert!(n > 100, "{n} states checked");
}

/// A road that bends away from straight lines near the ego is refused, naming the file and
/// the deviation; so are unknown egos and a t0 without history.
#[test]
fn unsupported_road_and_bad_ego_are_typed_errors() {
    let fixture = repo().join("python/train/tests/fixtures/commonroad/USA_US101-1_1_T-1.xml.gz");
    let scene = CommonRoadScene::read(&fixture).unwrap();
    let id = scene.tracks[0].id;
    let e = scene.scenario(Ego::Obstacle(999_999), 2.1).unwrap_err();
    assert!(
        matches!(e, CommonRoadError::Ego { .. }) && e.to_string().contains("obstacle 999999"),
        "{e}"
    );
    let e = scene.scenario(Ego::Obstacle(id), 0.0).unwrap_err();
    assert!(e.to_string().contains("history"), "{e}");
    // Wave every lanelet bound ±3 m with an 80 m wavelength: no polynomial shape straightens it.
    let mut raw = RawScenario::read(&fixture).unwrap();
    for ll in &mut raw.lanelets {
        for p in ll.left.iter_mut().chain(ll.right.iter_mut()) {
            p[1] += 3.0 * (p[0] * std::f64::consts::TAU / 80.0).sin();
        }
    }
    let bent = CommonRoadScene::from_raw(raw);
    let msg = match bent {
        Ok(s) => s
            .scenario(Ego::Obstacle(id), s.default_t0(Ego::Obstacle(id)).unwrap())
            .unwrap_err()
            .to_string(),
        Err(e) => e.to_string(),
    };
    assert!(
        msg.contains("USA_US101-1_1_T-1.xml.gz") && msg.contains("not supported"),
        "{msg}"
    );
}

/// Malformed files are typed errors naming file, element and line.
#[test]
fn malformed_files_name_the_element_and_line() {
    let dir = std::env::temp_dir().join(format!("nudge-cr-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let write = |name: &str, text: &str| {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p
    };
    let head = r#"<commonRoad commonRoadVersion="2020a" timeStepSize="0.1" benchmarkID="X">"#;
    let lanelet = "<lanelet id=\"1\"><leftBound><point><x>0</x><y>2</y></point><point><x>50</x><y>2</y></point></leftBound>\
                   <rightBound><point><x>0</x><y>-2</y></point><point><x>50</x><y>-2</y></point></rightBound></lanelet>";
    let cases: Vec<(PathBuf, &str)> = vec![
        (write("a.xml", "<commonRoad"), "not valid XML"),
        (
            write(
                "b.xml",
                r#"<commonRoad commonRoadVersion="2017" timeStepSize="0.1"/>"#,
            ),
            "version",
        ),
        (
            write("c.xml", &format!("{head}\n</commonRoad>")),
            "no <lanelet>",
        ),
        (
            write(
                "d.xml",
                &format!(
                    "{head}\n{lanelet}\n<dynamicObstacle id=\"3\"><shape><rectangle><length>4</length><width>2</width></rectangle></shape>\n<initialState><position><point><x>1</x><y>nan</y></point></position><orientation><exact>0</exact></orientation><time><exact>0</exact></time><velocity><exact>1</exact></velocity></initialState></dynamicObstacle></commonRoad>"
                ),
            ),
            "obstacle 3 step 0 y",
        ),
    ];
    for (p, want) in cases {
        let e = RawScenario::read(&p).unwrap_err().to_string();
        assert!(e.contains(want) && e.contains(&*p.to_string_lossy()), "{e}");
    }
    let e = RawScenario::read(write("d.xml", &format!("{head}\n{lanelet}\n<dynamicObstacle id=\"3\"><shape><rectangle><length>4</length><width>2</width></rectangle></shape>\n<initialState><position><point><x>1</x><y>nan</y></point></position></initialState></dynamicObstacle></commonRoad>"))).unwrap_err();
    assert!(
        e.to_string().contains("line 4") && e.to_string().contains("obstacle 3 time"),
        "{e}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
    let _ = Path::new("");
}

/// `nudge simulate --commonroad FILE --ego ID` writes the scenario, the records and one
/// solution whose states step by one file time step from t0; a missing ego flag, an unknown
/// ego and a missing --out are refused before any run, naming the problem.
#[test]
fn cli_plans_in_a_commonroad_file_and_writes_a_solution() {
    use nudge::cli::{ExitStatus, run};
    let fixture = repo().join("python/train/tests/fixtures/commonroad/USA_US101-1_1_T-1.xml.gz");
    let out = std::env::temp_dir().join(format!("nudge-cr-cli-{}", std::process::id()));
    let assets = repo().join("assets");
    let args = |extra: &[&str]| {
        let mut v: Vec<String> = ["nudge", "simulate", "--commonroad"]
            .map(String::from)
            .to_vec();
        v.push(fixture.to_string_lossy().into_owned());
        v.extend(
            [
                "--predictor",
                "constant_velocity",
                "--world",
                "log_replay",
                "--threads",
                "1",
            ]
            .map(String::from),
        );
        v.extend(extra.iter().map(|s| (*s).to_string()));
        v
    };
    let o = out.to_string_lossy().into_owned();
    assert_eq!(
        run(args(&["--ego", "484", "--out", &o]), &assets),
        ExitStatus::Success
    );
    let sol = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "xml"))
        .expect("a solution file");
    let text = std::fs::read_to_string(&sol).unwrap();
    assert!(
        text.contains("benchmark_id=\"KS2:SM1:USA_US101-1_1_T-1:2020a\""),
        "{text}"
    );
    assert!(text.contains("planningProblem=\"484\""));
    let times: Vec<i64> = text
        .split("<time>")
        .skip(1)
        .map(|t| t.split('<').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(times[0], 21, "t0 2.1 s is time step 21");
    assert!(times.windows(2).all(|w| w[1] == w[0] + 1) && times.len() > 10);
    assert!(
        out.join("USA_US101-1_1_T-1-t02.1-ego484.safetensors")
            .exists()
    );
    assert_eq!(run(args(&["--out", &o]), &assets), ExitStatus::Refused);
    assert_eq!(
        run(args(&["--ego", "7", "--out", &o]), &assets),
        ExitStatus::Refused
    );
    assert_eq!(run(args(&["--ego", "484"]), &assets), ExitStatus::Usage);
    std::fs::remove_dir_all(&out).unwrap();
}

/// A planning problem's ego starts at its initial state (mapped into the road frame), with a
/// history extrapolated back at its speed and heading and no logged future; the neighbours'
/// histories before the scene's first step are extrapolated the same way.
#[test]
fn planning_problem_ego_starts_at_its_initial_state() {
    let fixture = repo().join("python/train/tests/fixtures/commonroad/USA_US101-1_1_T-1.xml.gz");
    let scene = CommonRoadScene::read(&fixture).unwrap();
    let pp = scene.raw.planning_problems[0].clone();
    assert_eq!(pp.id, 482);
    let ego = Ego::PlanningProblem(pp.id);
    let t0 = scene.default_t0(ego).unwrap();
    #[allow(clippy::cast_precision_loss)]
    let want_t0 = pp.initial.step as f64 * scene.raw.dt;
    assert!((t0 - want_t0).abs() < 1e-12);
    let sc = scene.scenario(ego, t0).unwrap();
    assert_eq!(sc.agent_ids[0], 482);
    let start = scene.frame.to_road([pp.initial.x, pp.initial.y]);
    let last = sc.position(0, 7);
    assert!((last[0] - start[0]).hypot(last[1] - start[1]) < 1e-9);
    let heading = scene
        .frame
        .heading_to_road([pp.initial.x, pp.initial.y], pp.initial.orientation);
    for k in 0..7 {
        let p = sc.position(0, k);
        #[allow(clippy::cast_precision_loss)]
        let back = (7 - k) as f64 * 0.3 * pp.initial.velocity;
        let want = [
            start[0] - back * heading.cos(),
            start[1] - back * heading.sin(),
        ];
        assert!(
            (p[0] - want[0]).hypot(p[1] - want[1]) < 1e-9,
            "history step {k}"
        );
    }
    assert!(
        sc.future_valid[..sc.n_future].iter().all(|v| !v),
        "the ego has no logged future"
    );
    assert!(sc.n_agents > 1 && sc.future_valid[sc.n_future..].iter().any(|v| *v));
}
