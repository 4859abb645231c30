//! Frame geometry against hand-computed pixel positions, the GIF decoded back, the MP4 pipe
//! through a stand-in ffmpeg, and every malformed input refused by name.
#![allow(clippy::unwrap_used)]

use nudge_planner::{BindingVehicle, StepStatus};

use super::*;

/// 10 px/m, 20 m behind and 40 m ahead, 2 m of verge, on a two-lane road y ∈ [0, 7] m: the
/// road area starts at row 38 (the caption) with y = 9 m, and the ego at x = 100 m sits at
/// column 200 (x = 80 m at the left edge).
fn settings() -> AnimationSettings {
    AnimationSettings {
        px_per_m: 10.0,
        behind_m: 20.0,
        ahead_m: 40.0,
        margin_m: 2.0,
        frame_s: 0.3,
    }
}

/// A reel of one shot: the ego (4 × 2 m) at (100, 5.5) with `heading`, and `others` as
/// (x, y) of 5 × 2 m cars at heading 0.
fn reel(heading: f64, others: &[[f64; 2]]) -> Reel {
    let mut agents = vec![[100.0, 5.5, heading]];
    agents.extend(others.iter().map(|p| [p[0], p[1], 0.0]));
    let mut sizes = vec![[4.0, 2.0]];
    sizes.extend(others.iter().map(|_| [5.0, 2.0]));
    Reel {
        title: "test".into(),
        lane_bounds: vec![0.0, 3.5, 7.0],
        sizes,
        shots: vec![Shot {
            agents,
            ego_speed: 12.0,
            collision: false,
            planned: None,
        }],
    }
}

/// A planned step from the ego of `reel` straight ahead at 12 m/s (3.6 m per step), the
/// others predicted ahead at 3 m per step, agent 1 binding at `step` with semi-axes (5, 2).
fn planned(reel: &Reel, step: usize) -> PlannedStep {
    let e = reel.shots[0].agents[0];
    let plan = (0..=6)
        .map(|k| [e[0] + 3.6 * f64::from(k), e[1], 0.0, 12.0])
        .collect();
    let predicted = reel.shots[0].agents[1..]
        .iter()
        .map(|a| (1..=6).map(|k| [a[0] + 3.0 * f64::from(k), a[1]]).collect())
        .collect();
    PlannedStep {
        status: StepStatus::Converged,
        mpc_s: 0.008,
        plan,
        predicted,
        binding: Some(BindingVehicle {
            agent: 1,
            step,
            b: 0.5,
            semi_axes: vec![[5.0, 2.0]; 6],
        }),
    }
}

/// The pixel box of `ink` below the caption band (the caption's colour key uses the inks
/// too).
fn road_bbox(c: &Canvas, ink: Ink) -> Option<[u32; 4]> {
    let mut b: Option<[u32; 4]> = None;
    for y in CAPTION_PX..c.height() {
        for x in 0..c.width() {
            if c.ink(x, y) == Some(ink) {
                b = Some(b.map_or([x, y, x, y], |b| {
                    [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)]
                }));
            }
        }
    }
    b
}

fn frame(r: &Reel) -> Canvas {
    let size = frame_size(r, &settings()).unwrap();
    draw_frame(r, 0, &settings(), size)
}

#[test]
fn the_frame_is_the_shown_road_at_the_scale_plus_the_caption() {
    let r = reel(0.0, &[]);
    // 60 m × 10 px/m; (7 m road + 2 × 2 m verge) × 10 px/m + 38 px caption.
    assert_eq!(frame_size(&r, &settings()).unwrap(), (600, 148));
    let odd = AnimationSettings {
        px_per_m: 2.5,
        ..settings()
    };
    // 150 × 65.5 → 150 × 66 (rounded up to even).
    assert_eq!(frame_size(&r, &odd).unwrap(), (150, 66));
    let huge = AnimationSettings {
        px_per_m: 1000.0,
        ..settings()
    };
    assert!(matches!(
        frame_size(&r, &huge),
        Err(AnimateError::Setting {
            field: "px_per_m",
            ..
        })
    ));
}

#[test]
fn the_view_maps_road_metres_to_pixels() {
    let r = reel(0.0, &[]);
    let v = View::new(&r, &settings(), 100.0);
    assert_eq!(v.to_px([80.0, 9.0]), [0.0, 38.0]);
    assert_eq!(v.to_px([100.0, 5.5]), [200.0, 73.0]);
    // y grows upwards: the road's left side (larger y) is higher in the frame.
    assert!(v.to_px([100.0, 7.0])[1] < v.to_px([100.0, 0.0])[1]);
}

#[test]
fn the_ego_box_lands_at_its_pixel_box() {
    let c = frame(&reel(0.0, &[]));
    // x 98..102 m → columns 180..220; y 4.5..6.5 m → rows 38 + (9 − 6.5)·10 = 63 .. 83.
    assert_eq!(road_bbox(&c, Ink::Outline), Some([180, 63, 220, 83]));
    assert_eq!(road_bbox(&c, Ink::Ego), Some([181, 64, 219, 82]));
    assert_eq!(c.ink(200, 73), Some(Ink::Ego));
    assert_eq!(c.ink(200, 60), Some(Ink::Road));
}

#[test]
fn a_box_turned_a_quarter_turn_swaps_its_extents() {
    let c = frame(&reel(std::f64::consts::FRAC_PI_2, &[]));
    // 2 m along x, 4 m along y around (100, 5.5): columns 190..210, rows 38 + 15 ± 20.
    assert_eq!(road_bbox(&c, Ink::Outline), Some([190, 53, 210, 93]));
}

#[test]
fn a_heading_turns_the_box_about_its_centre() {
    let h: f64 = 0.3;
    let c = frame(&reel(h, &[]));
    // The rotated rectangle's extents: ½(l|cos h| + w|sin h|), ½(l|sin h| + w|cos h|).
    let ex = 0.5 * (4.0 * h.cos() + 2.0 * h.sin()) * 10.0;
    let ey = 0.5 * (4.0 * h.sin() + 2.0 * h.cos()) * 10.0;
    let b = road_bbox(&c, Ink::Outline).unwrap();
    let want = [200.0 - ex, 73.0 - ey, 200.0 + ex, 73.0 + ey];
    for (got, want) in b.iter().zip(want) {
        assert!((f64::from(*got) - want).abs() <= 1.0, "{b:?} vs {want:?}");
    }
    // The front-left corner (heading > 0: up and right) is drawn, the opposite one is not.
    let fl = corners([100.0, 5.5, h], [4.0, 2.0])[2];
    let v = View::new(&reel(h, &[]), &settings(), 100.0);
    let p = v.point(fl);
    assert!(p.x > 200 && p.y < 73);
    let near = |x: i32, y: i32| {
        (-1..=1).any(|dx| {
            (-1..=1).any(|dy| {
                let i = c.ink(
                    u32::try_from(x + dx).unwrap(),
                    u32::try_from(y + dy).unwrap(),
                );
                i == Some(Ink::Outline)
            })
        })
    };
    assert!(near(p.x, p.y));
    assert!(!near(p.x, 2 * 73 - p.y));
}

#[test]
fn the_binding_vehicle_its_ellipses_and_the_plan_are_drawn_where_they_are() {
    let mut r = reel(0.0, &[[115.0, 2.0], [90.0, 2.0]]);
    let p = planned(&r, 2);
    r.shots[0].planned = Some(p);
    let c = frame(&r);
    // Agent 1 binds (orange) at x 112.5..117.5 → columns 325..375, y 1..3 → rows 98..118.
    assert_eq!(road_bbox(&c, Ink::Binding), Some([326, 99, 374, 117]));
    // Agent 2 is an ordinary car at columns 75..125.
    assert_eq!(c.ink(100, 108), Some(Ink::Other));
    // The bold ellipse at the binding step 2: centred on the prediction (115 + 3·3, 2) →
    // (440, 108), semi-axes 5 m × 2 m → 50 × 20 px (stroke 2 px).
    let b = road_bbox(&c, Ink::Tight).unwrap();
    for (got, want) in b.iter().zip([390, 88, 490, 128]) {
        assert!(got.abs_diff(want) <= 2, "{b:?}");
    }
    // The plan reaches its last state z_6 = (121.6, 5.5) → column 416.
    let plan = road_bbox(&c, Ink::Plan).unwrap();
    assert!(plan[2].abs_diff(416) <= 2, "{plan:?}");
    // The predicted reaction of agent 2 ends at (108, 2) → column 280.
    assert!(road_bbox(&c, Ink::Predicted).is_some());
    assert_eq!(c.ink(280, 108), Some(Ink::Predicted));
    // The caption says what binds.
    assert_eq!(
        step_line(&r, 0),
        "end after 0 steps  v 12.0 m/s".replace("end after 0 steps", "step 0/0  Converged")
            + "  plan 8.0 ms  binds on vehicle 1 (b 0.50)"
    );
    assert!(c.bbox(Ink::Text).is_some_and(|b| b[3] < CAPTION_PX));
}

#[test]
fn a_collision_colours_the_ego() {
    let mut r = reel(0.0, &[]);
    r.shots[0].collision = true;
    let c = frame(&r);
    assert_eq!(road_bbox(&c, Ink::Ego), None);
    assert_eq!(road_bbox(&c, Ink::Collision), Some([181, 64, 219, 82]));
    assert!(step_line(&r, 0).ends_with("COLLISION"));
}

/// A reel of `n` shots, the ego 3.6 m further along in each, every one but the last planned.
fn moving(n: usize) -> Reel {
    let mut r = reel(0.0, &[[115.0, 2.0]]);
    let first = r.shots[0].clone();
    r.shots = (0..n)
        .map(|k| {
            let mut s = first.clone();
            s.agents[0][0] += 3.6 * k as f64;
            s.agents[1][0] += 3.0 * k as f64;
            s
        })
        .collect();
    for k in 0..n - 1 {
        let mut one = r.clone();
        one.shots = vec![r.shots[k].clone()];
        r.shots[k].planned = Some(planned(&one, 0));
    }
    r
}

#[test]
fn the_gif_decodes_to_the_drawn_frames() {
    let dir = std::env::temp_dir().join(format!("nudge-anim-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let r = moving(5);
    let path = dir.join("run.gif");
    let w = animate(&r, &settings(), &path, None).unwrap();
    assert_eq!((w.frames, w.size, w.mp4), (5, (600, 148), None));
    let mut opts = gif::DecodeOptions::new();
    opts.set_color_output(gif::ColorOutput::Indexed);
    let mut d = opts.read_info(std::fs::File::open(&path).unwrap()).unwrap();
    assert_eq!((d.width(), d.height()), (600, 148));
    assert_eq!(d.global_palette().unwrap(), Ink::palette().as_slice());
    let mut k = 0;
    while let Some(f) = d.read_next_frame().unwrap() {
        assert_eq!((f.width, f.height, f.delay), (600, 148, 30));
        let drawn = draw_frame(&r, k, &settings(), (600, 148));
        assert!(f.buffer.as_ref() == drawn.indices(), "frame {k}");
        k += 1;
    }
    assert_eq!(k, 5);
    // Same reel, same bytes.
    let again = dir.join("again.gif");
    animate(&r, &settings(), &again, None).unwrap();
    assert_eq!(
        std::fs::read(&path).unwrap(),
        std::fs::read(&again).unwrap()
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A stand-in for ffmpeg: a script that copies its input to its last argument (or fails).
#[cfg(unix)]
fn fake_ffmpeg(dir: &std::path::Path, body: &str) -> std::path::PathBuf {
    use std::os::unix::fs::PermissionsExt;
    let p = dir.join("ffmpeg");
    std::fs::write(&p, format!("#!/bin/sh\n{body}\n")).unwrap();
    std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).unwrap();
    p
}

#[cfg(unix)]
#[test]
fn the_mp4_gets_every_frame_as_rgb24_and_a_failing_ffmpeg_is_an_error() {
    let dir = std::env::temp_dir().join(format!("nudge-mp4-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let r = moving(4);
    let ffmpeg = fake_ffmpeg(&dir, r#"for a; do out="$a"; done; cat > "$out""#);
    let (gif, mp4) = (dir.join("run.gif"), dir.join("run.mp4"));
    let w = animate(&r, &settings(), &gif, Some((&mp4, &ffmpeg))).unwrap();
    assert_eq!(w.mp4.as_deref(), Some(mp4.as_path()));
    let raw = std::fs::read(&mp4).unwrap();
    assert_eq!(raw.len(), 4 * 600 * 148 * 3);
    let first = draw_frame(&r, 0, &settings(), (600, 148)).rgb();
    assert!(raw[..first.len()] == first[..]);
    // The ego's centre pixel of frame 0 in rgb24.
    let at = (73 * 600 + 200) * 3;
    assert_eq!(raw[at..at + 3], Ink::Ego.rgb());
    let broken = fake_ffmpeg(&dir, "echo 'no encoder' >&2; exit 1");
    let e = animate(&r, &settings(), &gif, Some((&mp4, &broken))).unwrap_err();
    assert!(
        matches!(&e, AnimateError::Ffmpeg { stderr, .. } if stderr.contains("no encoder")),
        "{e}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A change that makes a reel malformed.
type Spoil = Box<dyn Fn(&mut Reel)>;

#[test]
fn malformed_reels_and_settings_are_refused_by_name() {
    let good = moving(3);
    good.validate().unwrap();
    let cases: Vec<(Spoil, &str)> = vec![
        (Box::new(|r| r.lane_bounds = vec![1.0]), "lane_bounds"),
        (Box::new(|r| r.lane_bounds = vec![3.0, 1.0]), "lane_bounds"),
        (Box::new(|r| r.sizes[1] = [0.0, 2.0]), "sizes"),
        (Box::new(|r| r.shots.clear()), "shots"),
        (
            Box::new(|r| r.shots = vec![r.shots[2].clone(); MAX_SHOTS + 1]),
            "shots",
        ),
        (
            Box::new(|r| r.shots[1].agents.pop().map(drop).unwrap_or(())),
            "frame 1 agents",
        ),
        (
            Box::new(|r| r.shots[2].agents[1][2] = f64::NAN),
            "frame 2 agents",
        ),
        (
            Box::new(|r| r.shots[0].ego_speed = f64::INFINITY),
            "frame 0 speed",
        ),
        (Box::new(|r| plan_of(r, 1).plan.truncate(1)), "frame 1 plan"),
        (
            Box::new(|r| plan_of(r, 0).predicted[0].pop().map(drop).unwrap_or(())),
            "frame 0 predicted",
        ),
        (
            Box::new(|r| plan_of(r, 0).predicted.clear()),
            "frame 0 predicted",
        ),
        (Box::new(|r| plan_of(r, 0).mpc_s = -1.0), "frame 0 mpc_s"),
        (Box::new(|r| binding_of(r).agent = 5), "frame 0 binding"),
        (Box::new(|r| binding_of(r).step = 6), "frame 0 binding"),
        (
            Box::new(|r| binding_of(r).semi_axes[3][1] = 0.0),
            "frame 0 semi_axes",
        ),
        (
            Box::new(|r| binding_of(r).b = f64::NAN),
            "frame 0 binding_b",
        ),
    ];
    for (spoil, item) in cases {
        let mut r = good.clone();
        spoil(&mut r);
        match r.validate() {
            Err(AnimateError::Invalid { item: got, .. }) => assert_eq!(got, item),
            other => panic!("{item}: {other:?}"),
        }
        let gif = std::env::temp_dir().join("nudge-never-written.gif");
        assert!(animate(&r, &settings(), &gif, None).is_err());
    }
    for (field, s) in [
        (
            "px_per_m",
            AnimationSettings {
                px_per_m: 0.0,
                ..settings()
            },
        ),
        (
            "behind_m",
            AnimationSettings {
                behind_m: -1.0,
                ..settings()
            },
        ),
        (
            "ahead_m",
            AnimationSettings {
                ahead_m: f64::NAN,
                ..settings()
            },
        ),
        (
            "margin_m",
            AnimationSettings {
                margin_m: f64::INFINITY,
                ..settings()
            },
        ),
        (
            "frame_s",
            AnimationSettings {
                frame_s: 0.0,
                ..settings()
            },
        ),
    ] {
        match s.validate() {
            Err(AnimateError::Setting { field: f, .. }) => assert_eq!(f, field),
            other => panic!("{field}: {other:?}"),
        }
    }
}

fn plan_of(r: &mut Reel, k: usize) -> &mut PlannedStep {
    r.shots[k].planned.as_mut().unwrap()
}

fn binding_of(r: &mut Reel) -> &mut BindingVehicle {
    plan_of(r, 0).binding.as_mut().unwrap()
}

#[test]
fn segments_are_clipped_to_the_frame() {
    let c = Canvas::new(600, 148, Ink::Road);
    // Horizontal through the frame: cut at the widened edges x = −2 and 602.
    assert_eq!(
        clip_segment(&c, [-100.0, 50.0], [700.0, 50.0]),
        Some(([-2.0, 50.0], [602.0, 50.0]))
    );
    // The diagonal y = x from far away enters at (−2, −2) and leaves at the bottom (150, 150).
    assert_eq!(
        clip_segment(&c, [-1e12, -1e12], [1e12, 1e12]),
        Some(([-2.0, -2.0], [150.0, 150.0]))
    );
    // Wholly outside, and non-finite.
    assert_eq!(clip_segment(&c, [-10.0, -10.0], [-10.0, 500.0]), None);
    assert_eq!(clip_segment(&c, [0.0, 0.0], [f64::NAN, 1.0]), None);
    assert_eq!(
        clip_segment(&c, [10.0, 10.0], [20.0, 20.0]),
        Some(([10.0, 10.0], [20.0, 20.0]))
    );
}

#[test]
fn far_away_geometry_is_drawn_clipped_at_once() {
    let mut r = reel(0.0, &[[115.0, 2.0], [90.0, 2.0]]);
    let mut p = planned(&r, 2);
    // A plan running off 10⁹ km ahead, a huge ellipse, a prediction far off the road.
    p.plan[6] = [1e12, 5.5, 0.0, 12.0];
    p.binding.as_mut().unwrap().semi_axes[0] = [1e9, 1e9];
    p.predicted[1][5] = [1e15, -1e15];
    r.shots[0].planned = Some(p);
    let t0 = std::time::Instant::now();
    let c = frame(&r);
    assert!(t0.elapsed().as_secs_f64() < 5.0);
    // The plan's last segment leaves through the right edge.
    assert!(road_bbox(&c, Ink::Plan).is_some_and(|b| b[2] == 599));
    // Vehicles longer than MAX_VEHICLE_M are refused.
    r.sizes[1] = [MAX_VEHICLE_M + 1.0, 2.0];
    let e = r.validate();
    assert!(
        matches!(&e, Err(AnimateError::Invalid { item, .. }) if item == "sizes"),
        "{e:?}"
    );
}
