//! [`Canvas`]: a frame buffer of palette indices that `embedded-graphics` draws into, and the
//! palette ([`Ink`]) every frame and the GIF share.

use std::convert::Infallible;

use embedded_graphics::Pixel;
use embedded_graphics::pixelcolor::PixelColor;
use embedded_graphics::prelude::{DrawTarget, OriginDimensions, Size};

/// The colours of an animation: a fixed palette, so that frames are palette indices (the
/// GIF's own format) with no colour quantisation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Ink {
    /// Beyond the road edges.
    Verge,
    /// The road surface.
    Road,
    /// Dashed lane boundaries.
    Marking,
    /// The road edges.
    Edge,
    /// The ego's box.
    Ego,
    /// Other vehicles' boxes.
    Other,
    /// The box of the vehicle the plan's safety binds on.
    Binding,
    /// Box outlines.
    Outline,
    /// The ego's executed path.
    Path,
    /// The step's plan.
    Plan,
    /// The others' predicted reaction to the plan.
    Predicted,
    /// The binding vehicle's safety ellipses.
    Ellipse,
    /// Its ellipse at the binding step.
    Tight,
    /// A box in collision.
    Collision,
    /// The caption band.
    Caption,
    /// Caption text.
    Text,
}

impl Ink {
    /// Every ink, in palette order (index = `ink as u8`).
    pub const ALL: [Self; 16] = [
        Self::Verge,
        Self::Road,
        Self::Marking,
        Self::Edge,
        Self::Ego,
        Self::Other,
        Self::Binding,
        Self::Outline,
        Self::Path,
        Self::Plan,
        Self::Predicted,
        Self::Ellipse,
        Self::Tight,
        Self::Collision,
        Self::Caption,
        Self::Text,
    ];

    /// (red, green, blue).
    #[must_use]
    pub const fn rgb(self) -> [u8; 3] {
        match self {
            Self::Verge => [46, 58, 46],
            Self::Road => [72, 72, 78],
            Self::Marking => [190, 190, 190],
            Self::Edge => [235, 235, 235],
            Self::Ego => [40, 130, 255],
            Self::Other => [175, 175, 175],
            Self::Binding => [255, 150, 40],
            Self::Outline => [15, 15, 15],
            Self::Path => [0, 215, 255],
            Self::Plan => [70, 230, 70],
            Self::Predicted => [255, 225, 30],
            Self::Ellipse => [230, 90, 90],
            Self::Tight => [255, 20, 20],
            Self::Collision => [255, 0, 255],
            Self::Caption => [20, 20, 24],
            Self::Text => [245, 245, 245],
        }
    }

    /// The palette as the GIF takes it: (r, g, b) of every ink in order, `[16 · 3]`.
    #[must_use]
    pub fn palette() -> Vec<u8> {
        Self::ALL.iter().flat_map(|i| i.rgb()).collect()
    }
}

impl PixelColor for Ink {
    type Raw = ();
}

/// A `width` × `height` frame (pixels, row-major from the top-left corner) of palette
/// indices ([`Ink`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Canvas {
    width: u32,
    height: u32,
    pixels: Vec<u8>,
}

impl Canvas {
    /// A frame filled with `ink`.
    #[must_use]
    pub fn new(width: u32, height: u32, ink: Ink) -> Self {
        Self {
            width,
            height,
            pixels: vec![ink as u8; width as usize * height as usize],
        }
    }

    /// Width (pixels).
    #[must_use]
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height (pixels).
    #[must_use]
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The ink at column `x`, row `y`; `None` outside the frame.
    #[must_use]
    pub fn ink(&self, x: u32, y: u32) -> Option<Ink> {
        (x < self.width && y < self.height)
            .then(|| Ink::ALL[usize::from(self.pixels[(y * self.width + x) as usize])])
    }

    /// The palette indices, row-major `[height · width]`.
    #[must_use]
    pub fn indices(&self) -> &[u8] {
        &self.pixels
    }

    /// The frame as rgb24, row-major `[height · width · 3]`.
    #[must_use]
    pub fn rgb(&self) -> Vec<u8> {
        self.pixels
            .iter()
            .flat_map(|&i| Ink::ALL[usize::from(i)].rgb())
            .collect()
    }

    /// The smallest rectangle (x0, y0, x1, y1) (pixels, inclusive) holding every pixel of
    /// `ink`; `None` when there is none.
    #[must_use]
    pub fn bbox(&self, ink: Ink) -> Option<[u32; 4]> {
        let mut b: Option<[u32; 4]> = None;
        for (i, &p) in self.pixels.iter().enumerate() {
            if p == ink as u8 {
                let (x, y) = ((i as u32) % self.width, (i as u32) / self.width);
                b = Some(b.map_or([x, y, x, y], |b| {
                    [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)]
                }));
            }
        }
        b
    }
}

impl OriginDimensions for Canvas {
    fn size(&self) -> Size {
        Size::new(self.width, self.height)
    }
}

impl DrawTarget for Canvas {
    type Color = Ink;
    type Error = Infallible;

    /// Sets every pixel inside the frame; pixels outside it are clipped.
    fn draw_iter<I>(&mut self, pixels: I) -> Result<(), Self::Error>
    where
        I: IntoIterator<Item = Pixel<Self::Color>>,
    {
        for Pixel(p, ink) in pixels {
            if let (Ok(x), Ok(y)) = (u32::try_from(p.x), u32::try_from(p.y))
                && x < self.width
                && y < self.height
            {
                self.pixels[(y * self.width + x) as usize] = ink as u8;
            }
        }
        Ok(())
    }
}
