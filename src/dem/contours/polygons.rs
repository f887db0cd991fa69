//! Contour polygons as `gdal_contour -p` draws them: the raster cut into bands between
//! consecutive levels, each band one multipolygon (outer rings with their holes) whose
//! edges are the contour lines of `contours` and, where the data stops, the raster's edge
//! and the edge of NoData half-way to the NoData centre (GDAL's quarter squares).
//!
//! How: every marching square (or quarter) is split along its level segments into pieces,
//! each in one band; a piece's band is read from a stretch of the square's boundary it
//! holds (the corner's band, stepped once per crossing passed). The pieces' edges are then
//! added per band with their direction, an edge cancelling its reverse (the two pieces on
//! either side lie in one band), and what is left is each band's boundary, walked into
//! rings. A square whose four corners share a band is one piece; its sides toward such a
//! square of the same band are not added at all, so memory follows the bands' boundaries,
//! not the raster's size. Full squares add the middle of each side as a vertex, where a
//! quartered neighbour has a corner.
//!
//! Bands and GDAL's attributes: band b holds the values v with level(b−1) ≤ v < level(b)
//! (after GDAL's nudge). The lowest band's minimum and, with fixed levels, the highest
//! band's maximum are the data's own extreme values; gdal_contour 3.6 writes 0 and
//! 4294967295 there (placeholders, not elevations).

use std::collections::{HashMap, HashSet};

use anyhow::{bail, Result};
use volterra_formats::heightfield::{GridGeoref, HeightRows};

use super::{checked_levels, for_each_square, level_range, level_value, to_map, Corner, Levels, Side, Square};

/// One band between two levels: its polygons in map coordinates, each an outer ring and
/// its holes, every ring closed (first vertex repeated last), outer rings
/// counter-clockwise and holes clockwise (RFC 7946).
#[derive(Debug, Clone, PartialEq)]
pub struct Band {
    /// The lower level (or the lowest elevation) and the upper level (or the highest).
    pub min: f64,
    pub max: f64,
    pub polygons: Vec<Vec<Vec<[f64; 2]>>>,
}

type Key = (u64, u64);
type Point = [f64; 2];
/// A directed edge: from, to.
type Edge = (Point, Point);
/// What lies along one side of a square: distance from its start corner, position, and
/// the level index crossing there (None: the side's middle).
type SideNode = (f64, Point, Option<i64>);

fn key(p: [f64; 2]) -> Key {
    (p[0].to_bits(), p[1].to_bits())
}

/// The band of a value: the count of levels it lies above (fixed levels), or one more
/// than the index of the highest level it lies above (levels offset + k · interval).
fn band_of(levels: &Levels, v: f64) -> i64 {
    let above = |k: i64| Square::above(level_value(levels, k), Corner { x: 0.0, y: 0.0, v });
    match levels {
        Levels::Interval { interval, offset } => {
            let mut k = ((v - offset) / interval).floor() as i64;
            while above(k + 1) {
                k += 1;
            }
            while !above(k) {
                k -= 1;
            }
            k + 1
        }
        Levels::Fixed(l) => (0..l.len() as i64).take_while(|&k| above(k)).count() as i64,
    }
}

/// Directed edges per band; an edge meeting its reverse cancels it.
#[derive(Default)]
struct Edges {
    edges: HashMap<(i64, Key, Key), Edge>,
}

impl Edges {
    fn add(&mut self, band: i64, a: [f64; 2], b: [f64; 2]) {
        if a == b {
            return;
        }
        if self.edges.remove(&(band, key(b), key(a))).is_none() {
            self.edges.insert((band, key(a), key(b)), (a, b));
        }
    }
}

impl Square {
    /// The corners in boundary order: upper left, upper right, lower right, lower left.
    fn corners_in_order(&self) -> [Corner; 4] {
        [self.upper_left, self.upper_right, self.lower_right, self.lower_left]
    }
}

/// The sides in boundary order, side i from corner i to corner i + 1 of `corners_in_order`.
const SIDES: [Side; 4] = [Side::Upper, Side::Right, Side::Lower, Side::Left];

fn side_index(s: Side) -> usize {
    SIDES.iter().position(|&t| t == s).expect("four sides")
}

/// Splits one square into its band pieces and adds their edges.
fn split_square(sq: &Square, levels: &Levels, edges: &mut Edges) {
    let corners = sq.corners_in_order();
    let (min, max) = sq.value_range();
    let ks: Vec<i64> = level_range(levels, min, max).collect();
    // Per side: the crossings (and a full square's side middle), by distance from the
    // side's start corner, with the level index crossing there.
    let mut per_side: [Vec<SideNode>; 4] = Default::default();
    for &k in &ks {
        let level = level_value(levels, k);
        for &(a, b) in sq.segment_sides(level) {
            for s in [a, b] {
                let i = side_index(s);
                let p = sq.point_on(s, level);
                let t = (p[0] - corners[i].x).abs() + (p[1] - corners[i].y).abs();
                per_side[i].push((t, p, Some(k)));
            }
        }
    }
    if !sq.quarter {
        for (i, list) in per_side.iter_mut().enumerate() {
            let m = Square::mid(corners[i], corners[(i + 1) % 4]);
            let t = (m.x - corners[i].x).abs() + (m.y - corners[i].y).abs();
            list.push((t, [m.x, m.y], None));
        }
    }
    // The boundary as nodes: per side its start corner, then what lies along it in order.
    let mut nodes: Vec<([f64; 2], Option<i64>)> = Vec::new();
    let mut side_of_node = Vec::new();
    let mut side_start = [0; 4];
    let mut crossing_node: HashMap<(usize, i64), usize> = HashMap::new();
    for (i, list) in per_side.iter_mut().enumerate() {
        list.sort_by(|a, b| a.0.total_cmp(&b.0));
        side_start[i] = nodes.len();
        nodes.push(([corners[i].x, corners[i].y], None));
        side_of_node.push(i);
        for &(_, p, k) in list.iter() {
            if let Some(k) = k {
                crossing_node.insert((i, k), nodes.len());
            }
            nodes.push((p, k));
            side_of_node.push(i);
        }
    }
    // Cut along each segment (a chord between two boundary nodes; the segments of a square
    // never cross), keeping each piece in boundary order.
    let n = nodes.len();
    let mut pieces: Vec<Vec<usize>> = vec![(0..n).collect()];
    for &k in &ks {
        for &(a, b) in sq.segment_sides(level_value(levels, k)) {
            let (a, b) = (crossing_node[&(side_index(a), k)], crossing_node[&(side_index(b), k)]);
            let Some(pi) = pieces.iter().position(|p| p.contains(&a) && p.contains(&b)) else { continue };
            let piece = pieces.swap_remove(pi);
            let at = |x: usize| piece.iter().position(|&y| y == x).expect("a node of the piece");
            let arc = |from: usize, to: usize| {
                let mut v = vec![piece[from]];
                let mut i = from;
                while i != to {
                    i = (i + 1) % piece.len();
                    v.push(piece[i]);
                }
                v
            };
            let (ia, ib) = (at(a), at(b));
            pieces.push(arc(ia, ib));
            pieces.push(arc(ib, ia));
        }
    }
    for piece in &pieces {
        // A stretch of the square's boundary in this piece: consecutive nodes that are
        // consecutive on the boundary too (every piece has one).
        let Some(j) = (0..piece.len()).find(|&j| piece[(j + 1) % piece.len()] == (piece[j] + 1) % n) else { continue };
        let start = piece[j];
        let side = side_of_node[start];
        let corner = corners[side];
        // The band of the side's start corner, stepped once per crossing passed on the
        // way along the side to the stretch.
        let mut band = band_of(levels, corner.v);
        for &(_, k) in &nodes[side_start[side] + 1..=start] {
            if let Some(k) = k {
                band += if Square::above(level_value(levels, k), corner) { -1 } else { 1 };
            }
        }
        for w in 0..piece.len() {
            edges.add(band, nodes[piece[w]].0, nodes[piece[(w + 1) % piece.len()]].0);
        }
    }
}

/// Which full squares have four corners in one band, for a sliding window of rows.
struct WholeRows<'a> {
    src: &'a dyn HeightRows,
    levels: &'a Levels,
    /// Squares of rows row − 1, row, row + 1 (columns −1..width): their band, or None.
    rows: [Vec<Option<i64>>; 3],
    row: i64,
    /// The bands of the last corner row read (row + 1), and a row's elevations.
    corners: Vec<Option<i64>>,
    cells: Vec<f32>,
}

impl<'a> WholeRows<'a> {
    fn new(src: &'a dyn HeightRows, levels: &'a Levels) -> Self {
        let w = src.size()[0];
        let mut whole = WholeRows { src, levels, rows: Default::default(), row: 0, corners: vec![None; w + 2], cells: vec![0.0; w] };
        whole.corners = whole.corner_row(-2);
        whole.rows = [whole.square_row(-1), whole.square_row(0), whole.square_row(1)];
        whole
    }

    /// The bands of corner row `row`, columns −1..=width (None: NoData or outside).
    fn corner_row(&mut self, row: i64) -> Vec<Option<i64>> {
        let [w, h] = self.src.size();
        if row < 0 || row >= h as i64 {
            return vec![None; w + 2];
        }
        self.src.read_row(row as usize, 0, &mut self.cells);
        let mut bands = Vec::with_capacity(w + 2);
        bands.push(None);
        bands.extend(self.cells.iter().map(|&v| v.is_finite().then(|| band_of(self.levels, v as f64))));
        bands.push(None);
        bands
    }

    /// Squares between corner rows row − 1 (the last read) and row, columns −1..width.
    fn square_row(&mut self, row: i64) -> Vec<Option<i64>> {
        let here = self.corner_row(row);
        let above = std::mem::replace(&mut self.corners, here);
        let here = &self.corners;
        (0..above.len() - 1)
            .map(|i| {
                let b = above[i]?;
                (above[i + 1]? == b && here[i]? == b && here[i + 1]? == b).then_some(b)
            })
            .collect()
    }

    fn advance_to(&mut self, row: i64) {
        while self.row < row {
            self.row += 1;
            let next = self.square_row(self.row + 1);
            self.rows.rotate_left(1);
            self.rows[2] = next;
        }
    }

    /// The band of square (col, row − 1 + dr) where its corners share one.
    fn at(&self, col: i64, dr: usize) -> Option<i64> {
        if col < -1 || col >= self.src.size()[0] as i64 {
            return None;
        }
        self.rows[dr][(col + 1) as usize]
    }
}

/// The contour polygons of the rows of `src` (on `grid`; NoData as NaN) between `levels`,
/// lowest band first, in map coordinates. The rows are read three times, in order: for
/// the elevation range, and by the squares and the whole-square bands a row apart.
pub fn contour_polygons(src: &dyn HeightRows, grid: &GridGeoref, levels: &Levels) -> Result<Vec<Band>> {
    let range = crate::dem::elevation_range(src);
    if let Some(why) = src.failure() {
        bail!("{why}");
    }
    let levels = checked_levels(range, levels)?;
    let Some((lo, hi)) = range else { return Ok(vec![]) };
    let mut whole = WholeRows::new(src, &levels);
    let mut edges = Edges::default();
    for_each_square(src, |sq, col, row| {
        whole.advance_to(row);
        let band = if sq.quarter { None } else { whole.at(col, 1) };
        let Some(band) = band else {
            split_square(sq, &levels, &mut edges);
            return;
        };
        // The sides toward a whole square of the same band would cancel: left out.
        let neighbours = [whole.at(col, 0), whole.at(col + 1, 1), whole.at(col, 2), whole.at(col - 1, 1)];
        let corners = sq.corners_in_order();
        for (i, nb) in neighbours.iter().enumerate() {
            if *nb == Some(band) {
                continue;
            }
            let (a, b) = (corners[i], corners[(i + 1) % 4]);
            let m = Square::mid(a, b);
            edges.add(band, [a.x, a.y], [m.x, m.y]);
            edges.add(band, [m.x, m.y], [b.x, b.y]);
        }
    });
    if let Some(why) = src.failure() {
        bail!("{why}");
    }
    let to_map = to_map(grid);
    let mut by_band: HashMap<i64, Vec<Edge>> = HashMap::new();
    for ((band, _, _), e) in edges.edges {
        by_band.entry(band).or_default().push(e);
    }
    let mut keys: Vec<i64> = by_band.keys().copied().collect();
    keys.sort_unstable();
    let fixed_count = match &levels {
        Levels::Fixed(l) => Some(l.len() as i64),
        Levels::Interval { .. } => None,
    };
    let lowest = band_of(&levels, lo);
    let mut bands = Vec::new();
    for b in keys {
        let polygons = assemble(walk_rings(&by_band[&b]));
        let polygons = polygons.into_iter().map(|poly| poly.into_iter().map(|r| r.into_iter().map(&to_map).collect()).collect());
        let min = if b == lowest { lo } else { level_value(&levels, b - 1) };
        let max = if fixed_count == Some(b) { hi } else { level_value(&levels, b) };
        bands.push(Band { min, max, polygons: polygons.collect() });
    }
    Ok(bands)
}

/// The boundary edges of one band (pixel space, the band's pieces on their left) walked
/// into closed rings: at a vertex where two rings touch, the walk turns as far left as it
/// can, so each ring stays on its own piece of the band.
fn walk_rings(edges: &[Edge]) -> Vec<Vec<Point>> {
    let mut out_of: HashMap<Key, Vec<usize>> = HashMap::with_capacity(edges.len());
    for (i, (a, _)) in edges.iter().enumerate() {
        out_of.entry(key(*a)).or_default().push(i);
    }
    let mut used = vec![false; edges.len()];
    let mut rings = Vec::new();
    for start in 0..edges.len() {
        if used[start] {
            continue;
        }
        let mut ring = vec![edges[start].0];
        let mut e = start;
        loop {
            used[e] = true;
            let (a, b) = edges[e];
            ring.push(b);
            let d_in = [b[0] - a[0], b[1] - a[1]];
            // The outgoing edge turning furthest left (largest signed angle).
            let next = out_of[&key(b)]
                .iter()
                .copied()
                .filter(|&j| !used[j])
                .max_by(|&i, &j| turn(d_in, edges[i]).total_cmp(&turn(d_in, edges[j])));
            match next {
                Some(j) => e = j,
                None => break,
            }
        }
        rings.push(ring);
    }
    rings
}

/// The signed angle from direction `d` to edge `e`'s direction (left positive).
fn turn(d: Point, e: Edge) -> f64 {
    let f = [e.1[0] - e.0[0], e.1[1] - e.0[1]];
    (d[0] * f[1] - d[1] * f[0]).atan2(d[0] * f[0] + d[1] * f[1])
}

/// Twice the signed area (positive: counter-clockwise with x east and y south taken as a
/// right-handed plane, which is how the pieces run). Taken about the first vertex: about
/// the origin, the products of coordinates in the thousands would drown the area of a ring
/// round one cell centre (a level equal to the centre's value: 1e-13 of a cell).
fn area2(r: &[[f64; 2]]) -> f64 {
    let o = r[0];
    r.windows(2).map(|w| (w[0][0] - o[0]) * (w[1][1] - o[1]) - (w[1][0] - o[0]) * (w[0][1] - o[1])).sum()
}

/// Whether `p` lies inside closed ring `r` (even-odd rule).
fn inside(p: [f64; 2], r: &[[f64; 2]]) -> bool {
    let mut c = false;
    for w in r.windows(2) {
        let (a, b) = (w[0], w[1]);
        if (a[1] > p[1]) != (b[1] > p[1]) && p[0] < a[0] + (p[1] - a[1]) / (b[1] - a[1]) * (b[0] - a[0]) {
            c = !c;
        }
    }
    c
}

/// Rings into polygons: outer rings (the pieces' orientation) each with the holes that
/// the smallest of them holds; every ring reversed for map coordinates (y north), so that
/// outer rings run counter-clockwise there and holes clockwise.
fn assemble(rings: Vec<Vec<[f64; 2]>>) -> Vec<Vec<Vec<[f64; 2]>>> {
    let bbox = |r: &[[f64; 2]]| {
        r.iter().fold([f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY], |b, p| {
            [b[0].min(p[0]), b[1].min(p[1]), b[2].max(p[0]), b[3].max(p[1])]
        })
    };
    let (mut outers, mut holes) = (Vec::new(), Vec::new());
    for r in rings {
        let a = area2(&r);
        if a > 0.0 {
            outers.push((bbox(&r), a, r));
        } else if a < 0.0 {
            holes.push(r);
        }
    }
    let mut polygons: Vec<Vec<Vec<[f64; 2]>>> = outers.iter().map(|(_, _, r)| vec![r.clone()]).collect();
    for hole in holes {
        let hb = bbox(&hole);
        let candidates: Vec<usize> = (0..outers.len())
            .filter(|&i| {
                let b = outers[i].0;
                b[0] <= hb[0] && b[1] <= hb[1] && b[2] >= hb[2] && b[3] >= hb[3]
            })
            .collect();
        // A hole may touch its outer ring at a vertex (where the walk parted them): test a
        // vertex of the hole that no candidate ring shares, strictly inside or outside.
        let shared: HashSet<Key> = candidates.iter().flat_map(|&i| outers[i].2.iter().map(|&p| key(p))).collect();
        let probe = hole.iter().copied().find(|&p| !shared.contains(&key(p))).unwrap_or(hole[0]);
        let smallest = |it: &mut dyn Iterator<Item = usize>| it.min_by(|&x, &y| outers[x].1.total_cmp(&outers[y].1));
        let host = smallest(&mut candidates.iter().copied().filter(|&i| inside(probe, &outers[i].2)))
            // Never dropped: rounding aside, the smallest ring round its box holds it.
            .or_else(|| smallest(&mut candidates.iter().copied()));
        if let Some(i) = host {
            polygons[i].push(hole);
        }
    }
    // Pixel space has y south: map coordinates flip the orientation.
    for poly in &mut polygons {
        for r in poly.iter_mut() {
            r.reverse();
        }
    }
    polygons
}
