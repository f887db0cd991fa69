//! Colour maps: a value's place in a range to a colour (linear RGB). Shared by every
//! renderer that colours by a data value and by the scalar bar drawn into PNG previews.

pub mod tables;

crate::setting_choice! {
    /// The colour map values are shown through.
    pub enum Colormap {
        /// matplotlib's viridis (perceptually uniform, dark blue to yellow).
        Viridis = "viridis",
        /// matplotlib's magma (black to light yellow).
        Magma = "magma",
        /// Moreland's diverging cool-warm (blue, grey, red), as matplotlib's coolwarm.
        Coolwarm = "coolwarm",
        /// Black to white (even in sRGB).
        Grey = "grey",
        /// matplotlib's hot (black, red, yellow, white): the usual PET overlay.
        Hot = "hot",
        /// matplotlib's rainbow (purple, blue, green, yellow, red), as PET-Rainbow overlays.
        Rainbow = "rainbow",
        /// Cartographers' hypsometric tints for elevation: lowland green, upland ochre, rock
        /// brown-grey, snow (the terrain renderers' default).
        Hypsometric = "hypsometric",
    }
}

/// The hypsometric tints at 21 evenly spaced values (linear RGB): stops green 0, ochre
/// 0.30, brown 0.60, grey 0.85, snow 1, linear between them (every stop is a table entry).
const HYPSOMETRIC: [[f32; 3]; 21] = {
    const STOPS: [(f32, [f32; 3]); 5] = [
        (0.0, [0.10, 0.28, 0.09]),
        (0.30, [0.36, 0.45, 0.16]),
        (0.60, [0.40, 0.27, 0.14]),
        (0.85, [0.45, 0.43, 0.40]),
        (1.0, [0.90, 0.90, 0.92]),
    ];
    let mut table = [[0.0f32; 3]; 21];
    let mut i = 0;
    while i < 21 {
        let f = i as f32 / 20.0;
        let mut k = 0;
        while k < 3 && f > STOPS[k + 1].0 {
            k += 1;
        }
        let (f0, c0) = STOPS[k];
        let (f1, c1) = STOPS[k + 1];
        let s = (f - f0) / (f1 - f0);
        let mut c = 0;
        while c < 3 {
            table[i][c] = c0[c] + s * (c1[c] - c0[c]);
            c += 1;
        }
        i += 1;
    }
    table
};

pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

impl Colormap {
    /// The colour (linear RGB) at t in [0, 1] (clamped; not finite: the low end), linear
    /// between the table's values.
    pub fn at(self, t: f64) -> [f32; 3] {
        let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.0 } as f32;
        let table: &[[f32; 3]] = match self {
            Colormap::Viridis => &tables::VIRIDIS,
            Colormap::Magma => &tables::MAGMA,
            Colormap::Coolwarm => &tables::COOLWARM,
            Colormap::Hot => &tables::HOT,
            Colormap::Rainbow => &tables::RAINBOW,
            Colormap::Hypsometric => &HYPSOMETRIC,
            Colormap::Grey => return [srgb_to_linear(t); 3],
        };
        let x = t * (table.len() - 1) as f32;
        let i = (x.floor() as usize).min(table.len() - 2);
        let f = x - i as f32;
        [0, 1, 2].map(|c| table[i][c] + f * (table[i + 1][c] - table[i][c]))
    }
}

/// What a frame shows through a colour map, for the scalar bar beside it: the quantity's
/// name, the map, and the values at its ends.
#[derive(Debug, Clone, PartialEq)]
pub struct ColourScale {
    pub title: String,
    pub colormap: Colormap,
    pub range: [f64; 2],
}
