//! [`AnimationSettings`] and the world → pixel transform of a frame ([`View`]).

use embedded_graphics::prelude::Point;
use serde::{Deserialize, Serialize};

use super::error::AnimateError;
use super::reel::Reel;

/// Height (pixels) of the caption band at the top of every frame: three lines of the 6 × 10
/// pixel font.
pub const CAPTION_PX: u32 = 38;

/// Largest frame side (pixels).
pub const MAX_SIDE_PX: u32 = 4096;

/// How an animation frames a run. Deserialises from JSON with every field optional (missing
/// fields take the [`Default`]) and unknown fields rejected.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AnimationSettings {
    /// Scale (pixels per metre, > 0).
    pub px_per_m: f64,
    /// Road shown behind the ego's centre (m, ≥ 0); the camera follows the ego along x.
    pub behind_m: f64,
    /// Road shown ahead of the ego's centre (m, > 0).
    pub ahead_m: f64,
    /// Verge shown beyond each road edge (m, ≥ 0).
    pub margin_m: f64,
    /// How long each frame shows (s, 0.01..=10; 0.3 s is real time: one planning step).
    pub frame_s: f64,
}

impl AnimationSettings {
    /// The defaults: 6 px/m, 30 m behind and 90 m ahead of the ego, 2 m of verge, real time.
    pub const DEFAULT: Self = Self {
        px_per_m: 6.0,
        behind_m: 30.0,
        ahead_m: 90.0,
        margin_m: 2.0,
        frame_s: 0.3,
    };

    /// Checks every field (the frame size is checked with the road, [`frame_size`]).
    ///
    /// # Errors
    /// [`AnimateError::Setting`] naming the first field out of range.
    pub fn validate(&self) -> Result<(), AnimateError> {
        let checks: [(&'static str, f64, bool, &'static str); 5] = [
            (
                "px_per_m",
                self.px_per_m,
                self.px_per_m > 0.0,
                "must be > 0",
            ),
            (
                "behind_m",
                self.behind_m,
                self.behind_m >= 0.0,
                "must be ≥ 0",
            ),
            ("ahead_m", self.ahead_m, self.ahead_m > 0.0, "must be > 0"),
            (
                "margin_m",
                self.margin_m,
                self.margin_m >= 0.0,
                "must be ≥ 0",
            ),
            (
                "frame_s",
                self.frame_s,
                (0.01..=10.0).contains(&self.frame_s),
                "must be in 0.01..=10 s",
            ),
        ];
        for (field, value, ok, reason) in checks {
            if !(ok && value.is_finite()) {
                return Err(AnimateError::Setting {
                    field,
                    value: value.to_string(),
                    reason,
                });
            }
        }
        Ok(())
    }
}

impl Default for AnimationSettings {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// (width, height) in pixels of every frame of `reel` under `settings` (validated): the
/// shown road length and width (road plus verges) at the scale, rounded up to even numbers
/// (video encoders need them), plus the caption band.
///
/// # Errors
/// [`AnimateError::Setting`] (field `px_per_m`) when a side would exceed [`MAX_SIDE_PX`].
pub fn frame_size(reel: &Reel, settings: &AnimationSettings) -> Result<(u32, u32), AnimateError> {
    let road = reel.lane_bounds[reel.lane_bounds.len() - 1] - reel.lane_bounds[0];
    let w = (settings.behind_m + settings.ahead_m) * settings.px_per_m;
    let h = (road + 2.0 * settings.margin_m) * settings.px_per_m + f64::from(CAPTION_PX);
    let even = |v: f64| -> Option<u32> {
        let v = v.ceil();
        (v <= f64::from(MAX_SIDE_PX)).then(|| {
            // In range: the cast is exact.
            #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
            let v = v as u32;
            v + v % 2
        })
    };
    match (even(w), even(h)) {
        (Some(w), Some(h)) => Ok((w.max(2), h)),
        _ => Err(AnimateError::Setting {
            field: "px_per_m",
            value: settings.px_per_m.to_string(),
            reason: "the frame would exceed 4096 pixels a side",
        }),
    }
}

/// The world → pixel transform of one frame: road-frame metres (x along travel, y to the
/// left) to pixel coordinates (column to the right, row down), x growing to the right and y
/// upwards, so the road's left side is at the top.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    /// World x (m) at the frame's left edge.
    pub x_left: f64,
    /// World y (m) at the top of the road area (just below the caption band).
    pub y_top: f64,
    /// Scale (pixels per metre).
    pub px_per_m: f64,
    /// Row (pixels) of the top of the road area: the caption band's height.
    pub top_px: f64,
}

impl View {
    /// The view of `reel`'s road under `settings` with the camera on world x `ego_x` (m).
    #[must_use]
    pub fn new(reel: &Reel, settings: &AnimationSettings, ego_x: f64) -> Self {
        Self {
            x_left: ego_x - settings.behind_m,
            y_top: reel.lane_bounds[reel.lane_bounds.len() - 1] + settings.margin_m,
            px_per_m: settings.px_per_m,
            top_px: f64::from(CAPTION_PX),
        }
    }

    /// Continuous pixel coordinates (column, row) of the world point `p` = (x, y) (m).
    #[must_use]
    pub fn to_px(&self, p: [f64; 2]) -> [f64; 2] {
        [
            (p[0] - self.x_left) * self.px_per_m,
            self.top_px + (self.y_top - p[1]) * self.px_per_m,
        ]
    }

    /// The pixel holding the world point `p` (m) (its continuous coordinates rounded;
    /// saturating far outside the frame).
    #[must_use]
    pub fn point(&self, p: [f64; 2]) -> Point {
        let q = self.to_px(p);
        // Saturating float → int casts: far-away points only need to stay far away.
        #[allow(clippy::cast_possible_truncation)]
        Point::new(q[0].round() as i32, q[1].round() as i32)
    }

    /// A length `m` (m) in pixels (rounded, at least 1).
    #[must_use]
    pub fn len_px(&self, m: f64) -> u32 {
        // Saturating cast of a non-negative length.
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let px = (m * self.px_per_m).round().max(1.0) as u32;
        px
    }
}
