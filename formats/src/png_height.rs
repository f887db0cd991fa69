//! PNG heightmaps: 8- or 16-bit greyscale with a vertical scale and offset, or RGB-encoded
//! elevation (Terrarium, Mapbox Terrain-RGB). A PNG carries no georeferencing: the cell
//! size comes from the scene (or the defaults below) and the origin is (0, 0).

use crate::error::{FormatError, Result};
use crate::heightfield::{Crs, GridUnits, Heightfield, NodataMask};
use crate::image::decode_png;
use crate::memory::Limits;
use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum HeightEncoding {
    /// elevation = vertical_offset + vertical_scale · grey value (8 or 16 bit).
    #[default]
    Grey,
    /// Mapzen Terrarium: elevation = (R·256 + G + B/256) − 32768 m.
    Terrarium,
    /// Mapbox Terrain-RGB: elevation = −10000 + (R·65536 + G·256 + B) · 0.1 m.
    Mapbox,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PngHeightOptions {
    pub encoding: HeightEncoding,
    /// Metres per grey level (Grey only). None: the elevations are the grey levels
    /// themselves, without a unit (info and the scalar bar say "grey level").
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vertical_scale: Option<f64>,
    /// Metres added after scaling (Grey only). Default 0.
    pub vertical_offset: f64,
    /// Metres between samples. None: one sample apart, without a unit (a PNG holds no
    /// cell size; info says "sample").
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cell_size: Option<f64>,
    /// A grey value that marks NoData (Grey only), e.g. 0 for some exports. Default none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub nodata: Option<u16>,
}

impl Default for PngHeightOptions {
    fn default() -> Self {
        PngHeightOptions { encoding: HeightEncoding::Grey, vertical_scale: None, vertical_offset: 0.0, cell_size: None, nodata: None }
    }
}

pub fn read_png_heightmap(path: &Path, opts: &PngHeightOptions, limits: &Limits) -> Result<Heightfield> {
    let cell_size = opts.cell_size.unwrap_or(1.0);
    if !(cell_size.is_finite() && cell_size > 0.0) {
        return Err(FormatError::invalid(path, format!("cell_size {cell_size} must be positive")));
    }
    let vertical_scale = opts.vertical_scale.unwrap_or(1.0);
    if !vertical_scale.is_finite() || !opts.vertical_offset.is_finite() {
        return Err(FormatError::invalid(path, "vertical_scale and vertical_offset must be finite"));
    }
    // Elevations in f32 (and a NoData bit) are built while the samples are held.
    let p = decode_png(path, limits, 4)?;
    let n = p.width * p.height;
    let mut nodata = NodataMask::default();
    let elevations: Vec<f32> = match opts.encoding {
        HeightEncoding::Grey => {
            if p.palette {
                // A palette of greys (as some exporters write 8-bit heightmaps) reads as its
                // grey levels; a palette of colours is no height.
                let coloured = p.samples.chunks_exact(p.channels).any(|px| px[0] != px[1] || px[1] != px[2]);
                if coloured {
                    return Err(FormatError::invalid(
                        path,
                        "a PNG with a colour palette is not a heightmap (its palette holds colours, not grey levels)",
                    ));
                }
            } else if p.channels > 2 {
                return Err(FormatError::invalid(path, "a colour PNG needs encoding = \"terrarium\" or \"mapbox\" to be read as heights"));
            }
            let grey = |i: usize| p.samples[i * p.channels];
            if let Some(nd) = opts.nodata {
                nodata = (0..n).map(|i| grey(i) == nd).collect();
                if nodata.count() == 0 {
                    nodata = NodataMask::default();
                }
            }
            (0..n).map(|i| if nodata.get(i) { f32::NAN } else { (opts.vertical_offset + vertical_scale * grey(i) as f64) as f32 }).collect()
        }
        enc => {
            if p.channels < 3 || p.bit_depth != 8 {
                return Err(FormatError::invalid(path, "RGB-encoded elevation needs an 8-bit RGB(A) PNG"));
            }
            (0..n)
                .map(|i| {
                    let s = &p.samples[i * p.channels..];
                    let (r, g, b) = (s[0] as f64, s[1] as f64, s[2] as f64);
                    (match enc {
                        HeightEncoding::Terrarium => r * 256.0 + g + b / 256.0 - 32768.0,
                        _ => -10000.0 + (r * 65536.0 + g * 256.0 + b) * 0.1,
                    }) as f32
                })
                .collect()
        }
    };
    // Metres only where given: the RGB encodings are metres by definition, grey levels
    // need a vertical scale, and a PNG holds no cell size at all.
    let units = GridUnits {
        cell_size_in_metres: opts.cell_size.is_some(),
        elevation_in_metres: opts.encoding != HeightEncoding::Grey || opts.vertical_scale.is_some(),
    };
    let mut notes = Vec::new();
    if !units.cell_size_in_metres {
        notes.push(
            "a PNG holds no cell size: samples are taken 1 apart, without a unit (give one in metres: cell_size in a scene, --cell-size)"
                .to_string(),
        );
    }
    if !units.elevation_in_metres {
        notes.push("a grey PNG holds levels, not heights: elevations are the grey levels (give metres per level: vertical_scale in a scene, --vertical-scale)".to_string());
    } else if opts.encoding == HeightEncoding::Grey {
        notes.push(format!("elevation = {} m + {} m × grey level", opts.vertical_offset, vertical_scale));
    }
    Ok(Heightfield {
        width: p.width,
        height: p.height,
        cell_size: [cell_size; 2],
        cell_size_native: [cell_size; 2],
        origin: [0.0, 0.0],
        crs: Crs::local(),
        elevations,
        nodata,
        nodata_value: opts.nodata.map(f64::from),
        notes,
        attributes: vec![
            ("data type".into(), format!("{}-bit PNG, {} channel(s){}", p.bit_depth, p.channels, if p.palette { ", palette" } else { "" })),
            ("encoding".into(), format!("{:?}", opts.encoding)),
        ],
        units,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::{write_png_grey16, write_png_rgb8, RgbImage};

    #[test]
    fn rgb_encodings_decode_to_known_elevations() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.png");
        // Terrarium: (R·256 + G + B/256) − 32768; Mapbox: −10000 + (R·65536 + G·256 + B)·0.1.
        let img = RgbImage { width: 2, height: 1, data: vec![128, 0, 0, 129, 44, 128] };
        write_png_rgb8(&p, &img).unwrap();
        let t =
            read_png_heightmap(&p, &PngHeightOptions { encoding: HeightEncoding::Terrarium, ..Default::default() }, &Default::default())
                .unwrap();
        assert_eq!(t.elevations, vec![0.0, 256.0 + 44.0 + 0.5]);
        assert!(t.units.elevation_in_metres && !t.units.cell_size_in_metres, "Terrarium is metres by definition");
        let m = read_png_heightmap(&p, &PngHeightOptions { encoding: HeightEncoding::Mapbox, ..Default::default() }, &Default::default())
            .unwrap();
        assert_eq!(m.elevations[0], (-10000.0 + 128.0 * 65536.0 * 0.1) as f32);
        assert_eq!(m.elevations[1], (-10000.0 + (129.0 * 65536.0 + 44.0 * 256.0 + 128.0) * 0.1) as f32);
        assert!(
            read_png_heightmap(&p, &PngHeightOptions::default(), &Default::default()).is_err(),
            "colour PNG read as grey must be refused"
        );
    }

    #[test]
    fn grey_scale_offset_cell_size_and_nodata() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("g.png");
        write_png_grey16(&p, 3, 2, &[0, 1, 2, 1000, 65535, 0]).unwrap();
        let opts = PngHeightOptions {
            vertical_scale: Some(0.5),
            vertical_offset: -10.0,
            cell_size: Some(25.0),
            nodata: Some(0),
            ..Default::default()
        };
        let h = read_png_heightmap(&p, &opts, &Default::default()).unwrap();
        assert_eq!((h.width, h.height), (3, 2));
        assert_eq!(h.cell_size, [25.0, 25.0]);
        assert_eq!(h.nodata.iter().collect::<Vec<_>>(), vec![true, false, false, false, false, true]);
        assert_eq!(h.elevations[1], -9.5);
        assert_eq!(h.elevations[3], 490.0);
        assert_eq!(h.elevations[4], (-10.0 + 0.5 * 65535.0) as f32);
        assert!(h.elevations[0].is_nan());
        assert_eq!(h.units, GridUnits::METRES);
        // Without a scale or a cell size the numbers carry no unit, and the notes say so.
        let bare = read_png_heightmap(&p, &PngHeightOptions::default(), &Default::default()).unwrap();
        assert_eq!(bare.units, GridUnits { cell_size_in_metres: false, elevation_in_metres: false });
        assert_eq!((bare.units.cell_size_unit(), bare.units.elevation_unit()), ("sample", "grey level"));
        assert_eq!(bare.elevations[3], 1000.0);
        assert!(bare.notes.iter().any(|n| n.contains("vertical_scale in a scene")), "{:?}", bare.notes);
        assert!(read_png_heightmap(&p, &PngHeightOptions { cell_size: Some(0.0), ..Default::default() }, &Default::default()).is_err());
    }

    fn write_palette_png(path: &std::path::Path, palette: &[u8], indices: &[u8]) {
        let f = std::fs::File::create(path).unwrap();
        let mut enc = png::Encoder::new(f, indices.len() as u32, 1);
        enc.set_color(png::ColorType::Indexed);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_palette(palette.to_vec());
        enc.write_header().unwrap().write_image_data(indices).unwrap();
    }

    /// A palette of greys reads as grey heights (it was refused as colour); a palette of
    /// colours is refused with a message that says so.
    #[test]
    fn grey_palettes_read_as_heights_and_colour_palettes_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let grey = dir.path().join("grey.png");
        write_palette_png(&grey, &[0, 0, 0, 100, 100, 100, 255, 255, 255], &[2, 0, 1, 1]);
        let h =
            read_png_heightmap(&grey, &PngHeightOptions { vertical_scale: Some(2.0), ..Default::default() }, &Default::default()).unwrap();
        assert_eq!(h.elevations, vec![510.0, 0.0, 200.0, 200.0]);
        let colour = dir.path().join("colour.png");
        write_palette_png(&colour, &[0, 0, 0, 200, 10, 10], &[0, 1]);
        let err = read_png_heightmap(&colour, &PngHeightOptions::default(), &Default::default()).unwrap_err().to_string();
        assert!(err.contains("colour palette") && err.contains("colour.png"), "{err}");
    }
}
