//! Targets of the second reliability round (issue 49): the CommonRoad reader and the solution
//! writer (`commonroad`), and the IDM world file (`world`).
//!
//! * `commonroad`: a shipped CommonRoad fixture (`python/train/tests/fixtures/commonroad`),
//!   mutated as text (numbers replaced by hostile tokens, character and undefined entity
//!   references, CDATA, DTDs, deep nesting, element and attribute floods, duplicated and
//!   deleted elements,
//!   bit flips, truncation), written plain or gzipped (sometimes as a gzip bomb). Oracle: a
//!   typed error naming the file, or a scenario whose every value passes an independent
//!   re-check of the reader's ranges; from an accepted file, the scene, an ego's scenario and
//!   a solution of random inputs (long drives off the lane map included) are built, each a
//!   typed error or finite.
//! * `world`: the shipped `assets/worlds/idm.json`, mutated as JSON (a value replaced by a
//!   hostile one, keys removed, unknown keys added, a key repeated, strings edited) and as
//!   bytes. Oracle: a typed error naming the file, or a population whose every driver lies in
//!   the physical ranges in code ([`nudge_sim::idm::PLAUSIBLE`]) and with which a short IDM
//!   closed loop stays finite.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use nudge::commonroad::xml::{MAX_COORD, MAX_ORIENTATION, MAX_SIZE, MAX_VELOCITY};
use nudge::commonroad::{CommonRoadScene, Ego, RawScenario, Solution};
use nudge_planner::{PlannerSettings, Scenario};
use nudge_predictor::ConstantVelocity;
use nudge_sim::idm::{
    PLAUSIBLE, PLAUSIBLE_DELTA, PLAUSIBLE_GAP_FLOOR, PLAUSIBLE_MAX_DECEL, PLAUSIBLE_THRESHOLD,
};
use nudge_sim::{IdmPopulation, SimConfig, World, WorldModel, simulate};

use super::{Outcome, Rng, kind};

/// Seeds of the two targets.
pub(crate) struct SurfaceSeeds {
    /// Uncompressed CommonRoad fixtures (XML text).
    pub xml: Vec<String>,
    /// The shipped IDM world file (JSON text).
    pub world: String,
    /// A shipped scene for the IDM closed loop.
    pub scene: Option<Scenario>,
}

pub(crate) fn seeds(repo: &Path) -> SurfaceSeeds {
    let dir = repo.join("python/train/tests/fixtures/commonroad");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .map(|rd| rd.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    files.sort();
    let xml = files
        .iter()
        .filter_map(|p| {
            let raw = std::fs::read(p).ok()?;
            let mut out = String::new();
            std::io::Read::read_to_string(
                &mut flate2::read::GzDecoder::new(raw.as_slice()),
                &mut out,
            )
            .ok()?;
            Some(out)
        })
        .collect();
    let world =
        std::fs::read_to_string(nudge_sim::idm_path(&repo.join("assets"))).unwrap_or_default();
    let scene =
        Scenario::from_file(repo.join("assets/scenes/us101-11_1-t02.1-ego144.safetensors")).ok();
    SurfaceSeeds { xml, world, scene }
}

static FILE_ID: AtomicU64 = AtomicU64::new(0);

/// A fresh scratch path in this process's temporary folder.
fn scratch(ext: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nudge-fuzz-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    dir.join(format!(
        "try-{}.{ext}",
        FILE_ID.fetch_add(1, Ordering::Relaxed)
    ))
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    let _ = enc.write_all(bytes);
    enc.finish().unwrap_or_default()
}

/// A hostile token for a number's text.
fn hostile_number(rng: &mut Rng) -> String {
    match rng.below(14) {
        0 => "nan".into(),
        1 => "inf".into(),
        2 => "-1e400".into(),
        3 => "2&#48;.0".into(),
        4 => "&#x32;5".into(),
        5 => "1&foo;".into(),
        6 => "&#0;".into(),
        7 => "<![CDATA[7.5]]>".into(),
        8 => "1&amp;2".into(),
        9 => String::new(),
        10 => "0x10".into(),
        11 => format!("{}", rng.wild()),
        12 => "&#xD800;".into(),
        _ => format!("{:.3}", rng.range(-2e5, 2e5)),
    }
}

/// Byte offsets of the text of every `<tag>` whose text is a number.
fn number_spans(text: &str) -> Vec<(usize, usize)> {
    let b = text.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while let Some(off) = text[i..].find('>') {
        let start = i + off + 1;
        let end = text[start..].find('<').map_or(text.len(), |e| start + e);
        let s = &text[start..end];
        if !s.trim().is_empty()
            && s.trim().parse::<f64>().is_ok()
            && start > 0
            && b[start - 1] == b'>'
        {
            out.push((start, end));
        }
        i = start;
        if out.len() > 20_000 {
            break;
        }
    }
    out
}

fn mutate_xml(rng: &mut Rng, text: &mut String) -> &'static str {
    match rng.below(12) {
        0..=3 => {
            let spans = number_spans(text);
            if spans.is_empty() {
                return "number (none)";
            }
            let (a, b) = spans[rng.below(spans.len())];
            text.replace_range(a..b, &hostile_number(rng));
            "number replaced"
        }
        4 => {
            let k = rng.pick(&[10usize, 70, 1000, 200_000]);
            let at = text.find("<lanelet").unwrap_or(text.len() / 2);
            text.insert_str(at, &format!("{}{}", "<a>".repeat(k), "</a>".repeat(k)));
            "deep nesting"
        }
        5 => {
            let at = text.find("<lanelet").unwrap_or(text.len() / 2);
            if rng.chance(0.3) {
                let k = rng.pick(&[3usize, 64, 65, 100_000]);
                let attrs: String = (0..k).map(|i| format!(" a{i}=\"\"")).collect();
                text.insert_str(at, &format!("<a{attrs}/>"));
                return "attribute flood";
            }
            let k = if rng.chance(0.1) {
                1_000_100
            } else {
                rng.below(50_000)
            };
            text.insert_str(at, &"<a/>".repeat(k));
            "element flood"
        }
        6 => {
            let decl = rng.pick(&[
                "<!DOCTYPE commonRoad [<!ENTITY z \"0\">]>",
                "<!DOCTYPE commonRoad [<!ENTITY a \"aaaaaaaaaa\"><!ENTITY b \"&a;&a;&a;&a;\">]>",
                "<!DOCTYPE commonRoad SYSTEM \"file:///etc/passwd\">",
            ]);
            let at = text.find("<commonRoad").unwrap_or(0);
            text.insert_str(at, decl);
            let spans = number_spans(text);
            if let Some(&(a, b)) = spans.get(rng.below(spans.len().max(1))) {
                text.replace_range(a..b, rng.pick(&["2&z;", "&b;", "1"]));
            }
            "DTD"
        }
        7 => {
            // Duplicate or delete one element block.
            let tag = rng.pick(&[
                "<dynamicObstacle",
                "<lanelet ",
                "<planningProblem",
                "<state>",
            ]);
            let close = match tag {
                "<dynamicObstacle" => "</dynamicObstacle>",
                "<lanelet " => "</lanelet>",
                "<planningProblem" => "</planningProblem>",
                _ => "</state>",
            };
            let starts: Vec<usize> = text.match_indices(tag).map(|(i, _)| i).collect();
            if starts.is_empty() {
                return "block (none)";
            }
            let a = starts[rng.below(starts.len())];
            let Some(e) = text[a..].find(close) else {
                return "block (unclosed)";
            };
            let b = a + e + close.len();
            if rng.chance(0.5) {
                let block = text[a..b].to_string();
                text.insert_str(b, &block);
                "block duplicated"
            } else {
                text.replace_range(a..b, "");
                "block deleted"
            }
        }
        8 => {
            let attr = rng.pick(&[
                ("commonRoadVersion=\"2020a\"", "commonRoadVersion=\"2018b\""),
                ("timeStepSize=\"0.1\"", "timeStepSize=\"0\""),
                ("timeStepSize=\"0.1\"", "timeStepSize=\"&#49;\""),
                ("timeStepSize=\"0.1\"", "timeStepSize=\"&bad;\""),
                ("timeStepSize=\"0.1\"", "timeStepSize=\"0.30000001\""),
            ]);
            *text = text.replacen(attr.0, attr.1, 1);
            "attribute"
        }
        9 => {
            let n = rng.below(text.len() + 1);
            let mut cut = n;
            while !text.is_char_boundary(cut) {
                cut -= 1;
            }
            text.truncate(cut);
            "truncation"
        }
        10 => {
            // Remove one closing tag.
            let closes: Vec<usize> = text.match_indices("</").map(|(i, _)| i).collect();
            if let Some(&a) = closes.get(rng.below(closes.len().max(1)))
                && let Some(e) = text[a..].find('>')
            {
                text.replace_range(a..=a + e, "");
            }
            "closing tag removed"
        }
        _ => {
            let mut bytes = std::mem::take(text).into_bytes();
            if !bytes.is_empty() {
                let i = rng.below(bytes.len());
                bytes[i] ^= 1 << rng.below(8);
            }
            *text = String::from_utf8_lossy(&bytes).into_owned();
            "bit flip"
        }
    }
}

/// An independent re-check of what the reader accepted: every value finite and in the
/// reader's documented ranges, states in strictly increasing time.
fn raw_plausible(raw: &RawScenario) -> Result<(), String> {
    let coord = |v: f64| v.is_finite() && v.abs() <= MAX_COORD;
    if !(raw.dt.is_finite() && raw.dt > 0.0) {
        return Err(format!("dt {}", raw.dt));
    }
    for ll in &raw.lanelets {
        if ll.left.len() < 2 || ll.right.len() < 2 {
            return Err(format!("lanelet {} with fewer than 2 points", ll.id));
        }
        if !ll.left.iter().chain(&ll.right).flatten().all(|&v| coord(v)) {
            return Err(format!("lanelet {} point out of range", ll.id));
        }
    }
    for o in &raw.obstacles {
        if !(o.length > 0.0 && o.length <= MAX_SIZE && o.width > 0.0 && o.width <= MAX_SIZE) {
            return Err(format!("obstacle {} size", o.id));
        }
        for w in o.states.windows(2) {
            if w[1].step <= w[0].step {
                return Err(format!("obstacle {} time not increasing", o.id));
            }
        }
        for s in &o.states {
            if !(coord(s.x)
                && coord(s.y)
                && s.orientation.abs() <= MAX_ORIENTATION
                && s.velocity.abs() <= MAX_VELOCITY)
            {
                return Err(format!("obstacle {} state {:?}", o.id, s));
            }
        }
    }
    Ok(())
}

pub(crate) fn commonroad_try(rng: &mut Rng, seeds: &SurfaceSeeds) -> Outcome {
    if seeds.xml.is_empty() {
        return Outcome::Refused("no seed".into());
    }
    let mut text = seeds.xml[rng.below(seeds.xml.len())].clone();
    for _ in 0..=rng.below(3) {
        mutate_xml(rng, &mut text);
    }
    let (bytes, ext) = match rng.below(8) {
        0..=3 => (text.into_bytes(), "xml"),
        4..=6 => (gzip(text.as_bytes()), "xml.gz"),
        _ => {
            // A gzip bomb: the text followed by a long run of spaces.
            let mut t = text.into_bytes();
            t.resize(t.len() + rng.pick(&[1usize << 20, 40 << 20]), b' ');
            (gzip(&t), "xml.gz")
        }
    };
    let path = scratch(ext);
    if std::fs::write(&path, &bytes).is_err() {
        return Outcome::Refused("scratch write".into());
    }
    let outcome = commonroad_judge(rng, &path);
    let _ = std::fs::remove_file(&path);
    outcome
}

fn commonroad_judge(rng: &mut Rng, path: &Path) -> Outcome {
    let raw = match RawScenario::read(path) {
        Err(e) => {
            if !e.to_string().contains(&*path.to_string_lossy()) {
                return Outcome::Invalid(format!("error does not name the file: {e}"));
            }
            return Outcome::Refused(kind(&e));
        }
        Ok(raw) => raw,
    };
    if let Err(why) = raw_plausible(&raw) {
        return Outcome::Invalid(format!("accepted: {why}"));
    }
    let scene = match CommonRoadScene::from_raw(raw) {
        Err(e) => return Outcome::LaterRefused(kind(&e)),
        Ok(s) => s,
    };
    let ego = match scene.raw.planning_problems.first() {
        Some(pp) if rng.chance(0.5) => Ego::PlanningProblem(pp.id),
        _ => Ego::Obstacle(scene.tracks[rng.below(scene.tracks.len().max(1))].id),
    };
    let t0 = match scene.default_t0(ego) {
        Err(e) => return Outcome::LaterRefused(kind(&e)),
        Ok(t) => t,
    };
    let sc = match scene.scenario(ego, t0) {
        Err(e) => return Outcome::LaterRefused(kind(&e)),
        Ok(sc) => sc,
    };
    let steps = rng.pick(&[1usize, 5, 30, 400]);
    let inputs: Vec<[f64; 2]> = (0..steps)
        .map(|_| {
            if rng.chance(0.02) {
                [rng.wild(), rng.wild()]
            } else {
                [rng.range(-0.3, 0.3), rng.range(-6.0, 4.0)]
            }
        })
        .collect();
    match Solution::of_inputs(&scene, (ego, t0), &sc, (&inputs, None), (1.4, 1.4)) {
        Err(e) => Outcome::LaterRefused(kind(&e)),
        Ok(sol) => {
            let finite = sol.states.iter().all(|s| {
                [s.pos[0], s.pos[1], s.steering, s.velocity, s.orientation]
                    .iter()
                    .all(|v| v.is_finite())
            });
            if !finite {
                return Outcome::Invalid("a solution state is not finite".into());
            }
            let xml = sol.to_xml();
            if xml.matches("<ksState>").count() != sol.states.len() {
                return Outcome::Invalid("the solution XML lost states".into());
            }
            Outcome::Valid
        }
    }
}

/// Numeric leaves of the world file a mutation may replace (JSON pointers).
const WORLD_LEAVES: [&str; 12] = [
    "/drivers/0/0",
    "/drivers/3/1",
    "/drivers/5/2",
    "/drivers/7/3",
    "/drivers/9/4",
    "/bounds/T/0",
    "/bounds/a_max/1",
    "/model/delta",
    "/model/max_decel_mps2",
    "/model/gap_floor_m",
    "/intrusion/threshold_m",
    "/intrusion/p_yield",
];

fn mutate_world(rng: &mut Rng, text: &mut String) -> &'static str {
    let Ok(mut v) = serde_json::from_str::<serde_json::Value>(text) else {
        // Already broken: a byte edit.
        let n = rng.below(text.len() + 1);
        let mut cut = n;
        while !text.is_char_boundary(cut) {
            cut -= 1;
        }
        text.truncate(cut);
        return "truncation";
    };
    let what = match rng.below(8) {
        0..=2 => {
            let at = rng.pick(&WORLD_LEAVES);
            if let Some(x) = v.pointer_mut(at) {
                *x = match rng.below(6) {
                    0 => serde_json::json!("x"),
                    1 => serde_json::Value::Null,
                    2 | 3 => serde_json::json!(rng.range(0.0, 3.5)),
                    _ => serde_json::json!(rng.wild()),
                };
            }
            "value replaced"
        }
        3 => {
            let key = rng.pick(&[
                "units",
                "model",
                "bounds",
                "drivers",
                "driver_sources",
                "intrusion",
            ]);
            if let Some(o) = v.as_object_mut() {
                o.remove(key);
            }
            "key removed"
        }
        4 => {
            let at = rng.pick(&["", "/model", "/units", "/bounds", "/intrusion"]);
            if let Some(o) = v.pointer_mut(at).and_then(serde_json::Value::as_object_mut) {
                o.insert("unknown_key".into(), serde_json::json!(1));
            }
            "unknown key"
        }
        5 => {
            // Wide bounds and an absurd driver inside them.
            if let Some(b) = v.pointer_mut("/bounds/a_max") {
                *b = serde_json::json!([1e-3, 1e3]);
            }
            if let Some(x) = v.pointer_mut("/drivers/0/2") {
                *x = serde_json::json!(rng.range(6.0, 900.0));
            }
            "absurd driver in a wide box"
        }
        6 => {
            if let Some(d) = v
                .pointer_mut("/drivers")
                .and_then(serde_json::Value::as_array_mut)
            {
                let keep = rng.below(d.len() + 1);
                d.truncate(keep);
            }
            "drivers truncated"
        }
        _ => {
            *text = serde_json::to_string(&v).unwrap_or_default();
            *text = text.replacen("\"schema\":", "\"schema\":\"nudge.idm/1\",\"schema\":", 1);
            return "repeated key";
        }
    };
    *text = serde_json::to_string(&v).unwrap_or_default();
    what
}

pub(crate) fn world_try(rng: &mut Rng, seeds: &SurfaceSeeds) -> Outcome {
    let mut text = seeds.world.clone();
    for _ in 0..rng.below(3) {
        mutate_world(rng, &mut text);
    }
    let path = Path::new("fuzz-world.json");
    let pop = match IdmPopulation::from_json(&text, path) {
        Err(e) => {
            if !e.to_string().contains("fuzz-world.json") {
                return Outcome::Invalid(format!("error does not name the file: {e}"));
            }
            return Outcome::Refused(kind(&e));
        }
        Ok(p) => p,
    };
    for (i, d) in pop.drivers.iter().enumerate() {
        let p = [d.t, d.s0, d.a_max, d.b, d.v0_ratio];
        for (k, (&x, &(lo, hi))) in p.iter().zip(&PLAUSIBLE).enumerate() {
            if !(lo..=hi).contains(&x) {
                return Outcome::Invalid(format!("driver {i} parameter {k} = {x} accepted"));
            }
        }
    }
    let m = &pop.model;
    if !(m.delta > 0.0
        && m.delta <= PLAUSIBLE_DELTA
        && m.max_decel > 0.0
        && m.max_decel <= PLAUSIBLE_MAX_DECEL
        && m.gap_floor > 0.0
        && m.gap_floor <= PLAUSIBLE_GAP_FLOOR
        && pop.intrusion.threshold_m.abs() <= PLAUSIBLE_THRESHOLD
        && (0.0..=1.0).contains(&pop.intrusion.p_yield))
    {
        return Outcome::Invalid(format!(
            "model {m:?} / intrusion {:?} accepted",
            pop.intrusion
        ));
    }
    let Some(sc) = &seeds.scene else {
        return Outcome::Valid;
    };
    let cfg = SimConfig {
        world: World::Idm,
        max_steps: 4,
        ..SimConfig::default()
    };
    let mut cv = ConstantVelocity::default();
    match simulate(
        sc,
        &PlannerSettings::default(),
        &cfg,
        rng.next_u64() % 1000,
        &mut cv,
        WorldModel::Idm(&pop),
    ) {
        Err(e) => Outcome::LaterRefused(kind(&e)),
        Ok(rec) => {
            if rec
                .steps
                .iter()
                .all(|s| s.ego.iter().all(|v| v.is_finite()))
            {
                Outcome::Valid
            } else {
                Outcome::Invalid("an IDM run gave a non-finite ego state".into())
            }
        }
    }
}
