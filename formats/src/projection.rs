//! Longitude and latitude of map coordinates, for the projected CRSs DEMs mostly come in —
//! UTM zones (WGS 84: EPSG 32601–32660 north, 32701–32760 south; NAD83: 26901–26923;
//! ETRS89: 25828–25838) and Web Mercator (3857) — as `gdalinfo` prints a projected raster's
//! corners. Geographic CRSs give their own coordinates. Others: None (there is no PROJ here).
//!
//! The transverse Mercator inverse is Krüger's series to n⁴ (Karney 2011, eq. 15, 19, with
//! the coefficients of the rectifying radius A and of the β and δ sums): within 1e-9° of
//! PROJ's over a UTM zone (checked against `gdaltransform`). Latitudes and longitudes are
//! on the CRS's own datum (WGS 84 and GRS 80 differ by 0.1 mm in the semi-minor axis;
//! NAD83 and ETRS89 are their own datums, as gdalinfo's corner coordinates are).

use crate::heightfield::Crs;

/// The WGS 84 ellipsoid (GRS 80 differs in 1/f by 1e-11: far below the series' error).
const A_WGS84: f64 = 6_378_137.0;
const F_WGS84: f64 = 1.0 / 298.257223563;

/// How a CRS's map coordinates become longitude and latitude.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Projection {
    Geographic,
    /// UTM zone (1–60), south.
    Utm(u32, bool),
    WebMercator,
}

fn projection(crs: &Crs) -> Option<Projection> {
    if crs.geographic {
        return Some(Projection::Geographic);
    }
    let code = crs.epsg?;
    Some(match code {
        32601..=32660 => Projection::Utm(code - 32600, false),
        32701..=32760 => Projection::Utm(code - 32700, true),
        26901..=26923 => Projection::Utm(code - 26900, false),
        25828..=25838 => Projection::Utm(code - 25800, false),
        3857 | 900913 => Projection::WebMercator,
        _ => return None,
    })
}

/// Whether `lonlat` knows `crs`.
pub fn knows(crs: &Crs) -> bool {
    projection(crs).is_some()
}

/// [longitude, latitude] in degrees of map point (x, y) in `crs` (its units), where the
/// CRS is one this module converts (see the module doc).
pub fn lonlat(crs: &Crs, x: f64, y: f64) -> Option<[f64; 2]> {
    match projection(crs)? {
        Projection::Geographic => Some([x, y]),
        Projection::Utm(zone, south) => {
            let (e, n) = (x * crs.metres_per_unit, y * crs.metres_per_unit);
            let central = -183.0 + 6.0 * zone as f64;
            Some(transverse_mercator_inverse(e - 500_000.0, if south { n - 10_000_000.0 } else { n }, central, 0.9996))
        }
        Projection::WebMercator => {
            let (e, n) = (x * crs.metres_per_unit, y * crs.metres_per_unit);
            let lon = (e / A_WGS84).to_degrees();
            let lat = (2.0 * (n / A_WGS84).exp().atan() - std::f64::consts::FRAC_PI_2).to_degrees();
            Some([lon, lat])
        }
    }
}

/// Longitude and latitude (degrees) of a point `x` east and `y` north of a transverse
/// Mercator projection's origin on the equator at `central` longitude, scale `k0`.
fn transverse_mercator_inverse(x: f64, y: f64, central: f64, k0: f64) -> [f64; 2] {
    let n = F_WGS84 / (2.0 - F_WGS84);
    let (n2, n3, n4) = (n * n, n * n * n, n * n * n * n);
    let a = A_WGS84 / (1.0 + n) * (1.0 + n2 / 4.0 + n4 / 64.0);
    let beta = [
        n / 2.0 - 2.0 * n2 / 3.0 + 37.0 * n3 / 96.0 - n4 / 360.0,
        n2 / 48.0 + n3 / 15.0 - 437.0 * n4 / 1440.0,
        17.0 * n3 / 480.0 - 37.0 * n4 / 840.0,
        4397.0 * n4 / 161_280.0,
    ];
    let delta = [
        2.0 * n - 2.0 * n2 / 3.0 - 2.0 * n3 + 116.0 * n4 / 45.0,
        7.0 * n2 / 3.0 - 8.0 * n3 / 5.0 - 227.0 * n4 / 45.0,
        56.0 * n3 / 15.0 - 136.0 * n4 / 35.0,
        4279.0 * n4 / 630.0,
    ];
    let (xi, eta) = (y / (k0 * a), x / (k0 * a));
    let (mut xi1, mut eta1) = (xi, eta);
    for (j, b) in beta.iter().enumerate() {
        let k = 2.0 * (j + 1) as f64;
        xi1 -= b * (k * xi).sin() * (k * eta).cosh();
        eta1 -= b * (k * xi).cos() * (k * eta).sinh();
    }
    let chi = (xi1.sin() / eta1.cosh()).asin();
    let phi = chi + delta.iter().enumerate().map(|(j, d)| d * (2.0 * (j + 1) as f64 * chi).sin()).sum::<f64>();
    let lambda = eta1.sinh().atan2(xi1.cos());
    [central + lambda.to_degrees(), phi.to_degrees()]
}

/// Degrees as gdalinfo prints a corner: `123d 0' 0.00"W` (`hemispheres`: "WE" for a
/// longitude, degrees 3 wide; "SN" for a latitude, 2 wide).
pub fn dms(degrees: f64, hemispheres: &str) -> String {
    let h = hemispheres.as_bytes();
    let (sign, v) = if degrees < 0.0 { (h[0], -degrees) } else { (h[1], degrees) };
    // Hundredths of a second, rounded once, so 59.999" carries into the minute.
    let total = (v * 360_000.0).round() as u64;
    let (d, rest) = (total / 360_000, total % 360_000);
    let (m, cs) = (rest / 6000, rest % 6000);
    let width = if hemispheres == "WE" { 3 } else { 2 };
    format!("{d:>width$}d{m:>2}'{:>2}.{:02}\"{}", cs / 100, cs % 100, sign as char)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn utm(code: u32) -> Crs {
        Crs { epsg: Some(code), geographic: false, description: String::new(), metres_per_unit: 1.0 }
    }

    #[test]
    fn utm_corners_as_proj_gives_them() {
        // gdaltransform -s_srs EPSG:32610 -t_srs EPSG:4326 (GDAL 3.6, PROJ 9).
        for ((e, n), (lon, lat)) in [
            ((500000.0, 4200030.0), (-123.0, 37.9478599611966)),
            ((501800.0, 4198830.0), (-122.979515737028, 37.9370425919882)),
            ((833978.0, 9000000.0), (-104.418736639018, 80.5777892116084)),
            ((300000.0, 7000000.0), (-126.960352003158, 63.0739966028761)),
        ] {
            let [x, y] = lonlat(&utm(32610), e, n).unwrap();
            assert!((x - lon).abs() < 1e-9 && (y - lat).abs() < 1e-9, "({e}, {n}): {x}, {y} vs {lon}, {lat}");
        }
        // South: the false northing.
        let [_, lat] = lonlat(&utm(32733), 500000.0, 10_000_000.0).unwrap();
        assert!(lat.abs() < 1e-12);
        assert!(lonlat(&utm(2154), 0.0, 0.0).is_none(), "Lambert 93 is not converted here");
    }

    #[test]
    fn dms_as_gdalinfo_prints_it() {
        assert_eq!(dms(-123.0, "WE"), "123d 0' 0.00\"W");
        assert_eq!(dms(37.9478599611966, "SN"), "37d56'52.30\"N");
        assert_eq!(dms(-97.4849999999, "WE"), " 97d29' 6.00\"W");
    }
}
