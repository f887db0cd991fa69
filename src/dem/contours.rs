//! Contour lines of a heightfield as `gdal_contour` draws them (GDAL's marching squares,
//! `alg/marching_squares/`), so that the lines agree with GDAL's vertex for vertex:
//!
//! - Squares join four neighbouring cell centres; the raster is framed by a ring of
//!   NoData, so the lines reach the raster's outer edge (half a cell beyond the outer
//!   centres) instead of stopping at the outer centres.
//! - A square with one to three NoData corners is cut into four quarter squares round its
//!   centre, one per valid corner; a quarter's centre takes the mean of the valid corners,
//!   each mid-edge point the mean of its edge's valid ends (or the one valid end). Lines
//!   therefore stop half-way between a valid and a NoData cell.
//! - A corner counts as above a level when its value is greater, after GDAL's nudge: a
//!   value within 1e-6 of the level is raised by 1e-6 (so a value equal to a level is
//!   above it, and a line never passes exactly through a cell centre).
//! - The crossing on an edge is linear, worked out from the half of the edge that holds it
//!   (as GDAL does, so that a full square and its quartered neighbour give the same point).
//! - Saddles are always joined the same way (left with lower, right with upper), not by
//!   the centre value: GDAL's choice, which keeps lines of different levels from crossing.
//!
//! Segments are then joined into maximal lines, open ones ending on the raster's edge or at
//! NoData, closed ones repeating their first point last. Elevations are those the reader
//! gives: metres (a DEM in feet is converted on reading, where GDAL would draw feet).

use std::collections::HashMap;

use anyhow::{bail, Result};
use volterra_formats::heightfield::{GridGeoref, HeightRows};

/// Which levels to draw.
#[derive(Debug, Clone, PartialEq)]
pub enum Levels {
    /// offset + k · interval for every integer k (gdal_contour -i, -off).
    Interval { interval: f64, offset: f64 },
    /// These levels only (gdal_contour -fl).
    Fixed(Vec<f64>),
}

/// The most levels a raster may cross, as GDAL's limit: more is almost surely a wrong
/// interval (centimetres on a mountain range) and would take hours.
const MAX_LEVELS: i64 = 100_000;

/// One contour line in the raster's map coordinates (CRS units).
#[derive(Debug, Clone, PartialEq)]
pub struct ContourLine {
    pub level: f64,
    /// The vertices; a closed line repeats its first vertex last.
    pub points: Vec<[f64; 2]>,
}

impl ContourLine {
    pub fn is_closed(&self) -> bool {
        self.points.len() > 2 && self.points.first() == self.points.last()
    }
}

/// GDAL's nudge: a value within 1e-6 of the level counts as 1e-6 higher.
fn nudge(level: f64, value: f64) -> f64 {
    const TOLERANCE: f64 = 1e-6;
    if (level - value).abs() < TOLERANCE {
        value + TOLERANCE
    } else {
        value
    }
}

/// A corner of a square: pixel-space position (x east, y south; a cell's centre at
/// (col + 0.5, row + 0.5)) and value, NaN for NoData or outside the raster.
#[derive(Debug, Clone, Copy)]
struct Corner {
    x: f64,
    y: f64,
    v: f64,
}

/// The mean of the valid ones of two values (one valid: that one).
fn mean2(a: f64, b: f64) -> f64 {
    match (a.is_nan(), b.is_nan()) {
        (true, _) => b,
        (_, true) => a,
        _ => 0.5 * (a + b),
    }
}

/// A square between four corners; `quarter` when it is a quarter of a square cut at NoData.
#[derive(Debug, Clone, Copy)]
struct Square {
    upper_left: Corner,
    upper_right: Corner,
    lower_left: Corner,
    lower_right: Corner,
    quarter: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Side {
    Left,
    Lower,
    Right,
    Upper,
}

impl Square {
    fn nan_count(&self) -> usize {
        [self.upper_left, self.upper_right, self.lower_left, self.lower_right].iter().filter(|c| c.v.is_nan()).count()
    }

    fn centre(&self) -> Corner {
        let corners = [self.lower_left, self.upper_left, self.lower_right, self.upper_right];
        let sum: f64 = corners.iter().map(|c| if c.v.is_nan() { 0.0 } else { c.v }).sum();
        Corner {
            x: 0.5 * (self.upper_left.x + self.lower_right.x),
            y: 0.5 * (self.upper_left.y + self.lower_right.y),
            v: sum / (4 - self.nan_count()) as f64,
        }
    }

    fn mid(a: Corner, b: Corner) -> Corner {
        Corner { x: 0.5 * (a.x + b.x), y: 0.5 * (a.y + b.y), v: mean2(a.v, b.v) }
    }

    /// The quarters round the centre that hold a valid corner.
    fn quarters(&self) -> impl Iterator<Item = Square> {
        let (ul, ur, ll, lr) = (self.upper_left, self.upper_right, self.lower_left, self.lower_right);
        let c = self.centre();
        let (upper, lower) = (Self::mid(ul, ur), Self::mid(ll, lr));
        let (left, right) = (Self::mid(ul, ll), Self::mid(ur, lr));
        let q =
            |upper_left, upper_right, lower_left, lower_right| Square { upper_left, upper_right, lower_left, lower_right, quarter: true };
        [
            (!ul.v.is_nan()).then(|| q(ul, upper, left, c)),
            (!ur.v.is_nan()).then(|| q(upper, ur, c, right)),
            (!ll.v.is_nan()).then(|| q(left, c, ll, lower)),
            (!lr.v.is_nan()).then(|| q(c, right, lower, lr)),
        ]
        .into_iter()
        .flatten()
    }

    /// Where `level` crosses between positions p1 and p2 holding v1 and v2 (p1 the lower
    /// coordinate). A full square interpolates within the half of the edge that holds the
    /// crossing, so its points equal those of a quartered neighbour sharing the edge.
    fn crossing(level: f64, mut p1: f64, mut p2: f64, mut v1: f64, mut v2: f64, halve: bool) -> f64 {
        if halve {
            let (pm, vm) = (0.5 * (p1 + p2), 0.5 * (v1 + v2));
            let (n1, nm) = (nudge(level, v1), nudge(level, vm));
            if (n1 < level && level < nm) || (n1 > level && level > nm) {
                (p2, v2) = (pm, vm);
            } else {
                (p1, v1) = (pm, vm);
            }
        }
        let n1 = nudge(level, v1);
        let t = (level - n1) / (nudge(level, v2) - n1);
        p1 * (1.0 - t) + p2 * t
    }

    fn point_on(&self, side: Side, level: f64) -> [f64; 2] {
        let (ul, ur, ll, lr) = (self.upper_left, self.upper_right, self.lower_left, self.lower_right);
        let halve = !self.quarter;
        match side {
            Side::Left => [ul.x, Self::crossing(level, ll.y, ul.y, ll.v, ul.v, halve)],
            Side::Lower => [Self::crossing(level, ll.x, lr.x, ll.v, lr.v, halve), ll.y],
            Side::Right => [ur.x, Self::crossing(level, lr.y, ur.y, lr.v, ur.v, halve)],
            Side::Upper => [Self::crossing(level, ul.x, ur.x, ul.v, ur.v, halve), ul.y],
        }
    }

    /// The lowest and highest corner value.
    fn value_range(&self) -> (f64, f64) {
        let vs = [self.upper_left.v, self.upper_right.v, self.lower_left.v, self.lower_right.v];
        vs.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)))
    }

    /// Whether corner `c` counts as above `level` (after GDAL's nudge).
    fn above(level: f64, c: Corner) -> bool {
        level < nudge(level, c.v)
    }

    /// The sides each segment of `level` joins in this (NoData-free) square: none, one
    /// segment, or two at a saddle.
    fn segment_sides(&self, level: f64) -> &'static [(Side, Side)] {
        let above = |c: Corner| Self::above(level, c);
        let case = (above(self.upper_left) as u8)
            | (above(self.lower_left) as u8) << 1
            | (above(self.lower_right) as u8) << 2
            | (above(self.upper_right) as u8) << 3;
        use Side::*;
        match case {
            0 | 15 => &[],
            1 | 14 => &[(Upper, Left)],
            2 | 13 => &[(Left, Lower)],
            4 | 11 => &[(Lower, Right)],
            8 | 7 => &[(Right, Upper)],
            3 | 12 => &[(Upper, Lower)],
            6 | 9 => &[(Left, Right)],
            // The two saddles, always joined the same way.
            5 | 10 => &[(Left, Lower), (Right, Upper)],
            _ => unreachable!("four corner bits"),
        }
    }

    /// The segments of `level` in this (NoData-free) square.
    fn segments(&self, level: f64, out: &mut impl FnMut([f64; 2], [f64; 2])) {
        for &(a, b) in self.segment_sides(level) {
            out(self.point_on(a, level), self.point_on(b, level));
        }
    }
}

/// The level indices k whose level could lie in [min, max] (a margin for the nudge; the
/// marching case decides).
fn level_range(levels: &Levels, min: f64, max: f64) -> std::ops::Range<i64> {
    match levels {
        Levels::Interval { interval, offset } => {
            let lo = ((min - 2e-6 - offset) / interval).ceil() as i64;
            let hi = ((max + 2e-6 - offset) / interval).floor() as i64;
            lo..hi.max(lo - 1) + 1
        }
        Levels::Fixed(l) => {
            let lo = l.partition_point(|&v| v < min - 2e-6) as i64;
            let hi = l.partition_point(|&v| v <= max + 2e-6) as i64;
            lo..hi.max(lo)
        }
    }
}

fn level_value(levels: &Levels, k: i64) -> f64 {
    match levels {
        Levels::Interval { interval, offset } => k as f64 * interval + offset,
        Levels::Fixed(l) => l[k as usize],
    }
}

/// `levels` checked and put in order (fixed levels sorted, repeats dropped), refused where
/// elevations over `range` (the raster's valid ones) would cross more than `MAX_LEVELS`.
fn checked_levels(range: Option<(f64, f64)>, levels: &Levels) -> Result<Levels> {
    let levels = match levels {
        Levels::Interval { interval, offset } => {
            if !(interval.is_finite() && *interval > 0.0 && offset.is_finite()) {
                bail!("the contour interval must be a positive number and the offset finite");
            }
            levels.clone()
        }
        Levels::Fixed(l) => {
            if l.is_empty() || l.iter().any(|v| !v.is_finite()) {
                bail!("fixed contour levels must be finite numbers, at least one");
            }
            let mut l = l.clone();
            l.sort_by(f64::total_cmp);
            l.dedup();
            Levels::Fixed(l)
        }
    };
    if let Levels::Interval { interval, offset } = &levels {
        if let Some((lo, hi)) = range {
            if ((hi - offset) / interval).floor() - ((lo - offset) / interval).ceil() > MAX_LEVELS as f64 {
                bail!("an interval of {interval} over elevations {lo}…{hi} gives more than {MAX_LEVELS} levels");
            }
        }
    }
    Ok(levels)
}

/// Calls `visit` with every NoData-free square of the raster framed by a ring of NoData
/// (squares between rows row − 1 and row, columns col and col + 1), or with the quarters
/// of a square that has one to three NoData corners, as GDAL's marching squares visit
/// them, with the square's column and row (rows in order, each left to right). Reads each
/// row of `src` once, in order, holding two.
fn for_each_square(src: &dyn HeightRows, mut visit: impl FnMut(&Square, i64, i64)) {
    for_each_square_while(src, |sq, col, row| {
        visit(sq, col, row);
        true
    })
}

/// As `for_each_square`, stopping (no more rows read) once `visit` returns false.
fn for_each_square_while(src: &dyn HeightRows, mut visit: impl FnMut(&Square, i64, i64) -> bool) {
    let [w, h] = src.size();
    // Corner rows row − 1 and row (NaN beyond the raster and for NoData).
    let (mut above, mut below) = (vec![f32::NAN; w], vec![f32::NAN; w]);
    for row in 0..=h as i64 {
        std::mem::swap(&mut above, &mut below);
        if (row as usize) < h {
            src.read_row(row as usize, 0, &mut below);
            // A row that could not be read ends the pass: the caller reports `failure`,
            // not after reading the rest of a large raster.
            if src.failure().is_some() {
                return;
            }
        } else {
            below.fill(f32::NAN);
        }
        let value = |col: i64, r: i64| -> f64 {
            let cells = if r < row { &above } else { &below };
            if col < 0 || col >= w as i64 {
                return f64::NAN;
            }
            cells[col as usize] as f64
        };
        for col in -1..w as i64 {
            let corner = |c: i64, r: i64| Corner { x: c as f64 + 0.5, y: r as f64 + 0.5, v: value(c, r) };
            let sq = Square {
                upper_left: corner(col, row - 1),
                upper_right: corner(col + 1, row - 1),
                lower_left: corner(col, row),
                lower_right: corner(col + 1, row),
                quarter: false,
            };
            let go_on = match sq.nan_count() {
                4 => true,
                0 => visit(&sq, col, row),
                _ => sq.quarters().all(|q| visit(&q, col, row)),
            };
            if !go_on {
                return;
            }
        }
    }
}

/// Pixel space (x east, y south, in cells from the raster's north-west corner) to the
/// raster's map coordinates.
fn to_map(grid: &GridGeoref) -> impl Fn([f64; 2]) -> [f64; 2] {
    let [sx, sy] = grid.cell_size_native;
    let corner = [grid.origin[0] - 0.5 * sx, grid.origin[1] + 0.5 * sy];
    move |p: [f64; 2]| [corner[0] + p[0] * sx, corner[1] - p[1] * sy]
}

/// The contour lines of the rows of `src` (on `grid`; NoData as NaN) at `levels`, in map
/// coordinates, collected (see `contours_each`).
pub fn contours(src: &dyn HeightRows, grid: &GridGeoref, levels: &Levels) -> Result<Vec<ContourLine>> {
    let mut lines = Vec::new();
    contours_each(src, grid, levels, |line| {
        lines.push(line);
        Ok(())
    })?;
    Ok(lines)
}

/// The contour lines of the rows of `src` (on `grid`; NoData as NaN) at `levels`, in map
/// coordinates, each handed to `emit` as soon as it is complete: a closed line when its
/// last segment closes it, an open one once the row of squares below its ends has been
/// visited without extending it (the squares are visited row by row, and a line can only
/// grow from an end on the lower edge of the row just visited). The rows are read twice,
/// in order: for the elevation range (to refuse an interval that would draw more than
/// `MAX_LEVELS` levels), then to draw; what is held is two rows and the lines still open
/// — those crossing the current row, not every line of the raster. An error from `emit`
/// stops the reading and is returned.
pub fn contours_each(
    src: &dyn HeightRows,
    grid: &GridGeoref,
    levels: &Levels,
    mut emit: impl FnMut(ContourLine) -> Result<()>,
) -> Result<()> {
    let range = range_for(src, levels);
    // The range pass stops at a row that could not be read: say why, not what a partial
    // range makes of the levels.
    if let Some(why) = src.failure() {
        bail!("{why}");
    }
    let levels = checked_levels(range, levels)?;
    let to_map = to_map(grid);
    let mut open: HashMap<i64, OpenLines> = HashMap::new();
    // The lines that took a segment in the row of squares being visited, and in the one before.
    let (mut touched, mut touched_before): (Vec<LineId>, Vec<LineId>) = (Vec::new(), Vec::new());
    let mut row_visited = i64::MIN;
    let mut failed: Option<anyhow::Error> = None;
    let mut finish = |k: i64, line: std::collections::VecDeque<[f64; 2]>, failed: &mut Option<anyhow::Error>| {
        if failed.is_none() {
            let line = ContourLine { level: level_value(&levels, k), points: line.into_iter().map(&to_map).collect() };
            *failed = emit(line).err();
        }
    };
    for_each_square_while(src, |sq, _, row| {
        if row != row_visited {
            // Square row `row_visited` is done: its lower edge lies at y = row_visited + 0.5.
            // Lines it and the row before it touched whose ends both lie above that edge
            // can grow no more.
            let lower_edge = row_visited as f64 + 0.5;
            let mut done: Vec<LineId> = touched_before.drain(..).chain(touched.iter().copied()).collect();
            done.sort_unstable();
            done.dedup();
            for (k, id) in done {
                let lines = open.get_mut(&k).expect("a touched level");
                if let Some(line) = lines.take_if_ended(id, lower_edge) {
                    finish(k, line, &mut failed);
                }
            }
            std::mem::swap(&mut touched, &mut touched_before);
            row_visited = row;
        }
        let (min, max) = sq.value_range();
        for k in level_range(&levels, min, max) {
            let level = level_value(&levels, k);
            let lines = open.entry(k).or_default();
            sq.segments(level, &mut |a, b| {
                if a != b {
                    match lines.add(a, b) {
                        (id, false) => touched.push((k, id)),
                        (id, true) => {
                            let closed = lines.remove(id);
                            finish(k, closed, &mut failed);
                        }
                    }
                }
            });
        }
        failed.is_none()
    });
    if let Some(e) = failed {
        return Err(e);
    }
    if let Some(why) = src.failure() {
        bail!("{why}");
    }
    // Lines still open at the end (on the raster's last row, or stopped at NoData there).
    let mut keys: Vec<i64> = open.keys().copied().collect();
    keys.sort_unstable();
    for k in keys {
        let mut lines = open.remove(&k).expect("a key");
        for id in 0..lines.lines.len() {
            if lines.lines[id].is_some() {
                let line = lines.remove(id);
                finish(k, line, &mut failed);
            }
        }
    }
    failed.map_or(Ok(()), Err)
}

/// An open line: its level index and its place among that level's open lines.
type LineId = (i64, usize);

/// The open lines of one level while the squares are visited: each a run of points from
/// one end to the other, and the line each end point belongs to (a point of marching
/// squares meets at most two segment ends, so an end meets at most one more segment).
#[derive(Default)]
struct OpenLines {
    lines: Vec<Option<std::collections::VecDeque<[f64; 2]>>>,
    free: Vec<usize>,
    ends: HashMap<(u64, u64), usize>,
}

fn point_key(p: [f64; 2]) -> (u64, u64) {
    (p[0].to_bits(), p[1].to_bits())
}

impl OpenLines {
    /// Adds segment a–b (its ends equal bit for bit to those of the segments it meets: each
    /// crossing is worked out the same way from both squares sharing its edge): a new line,
    /// one line grown, or two joined. Returns the line and whether the segment closed it.
    fn add(&mut self, a: [f64; 2], b: [f64; 2]) -> (usize, bool) {
        let (at_a, at_b) = (self.ends.remove(&point_key(a)), self.ends.remove(&point_key(b)));
        match (at_a, at_b) {
            (None, None) => {
                let id = self.new_line([a, b].into_iter().collect());
                self.ends.insert(point_key(a), id);
                self.ends.insert(point_key(b), id);
                (id, false)
            }
            (Some(id), None) | (None, Some(id)) => {
                let (end, new) = if at_a.is_some() { (a, b) } else { (b, a) };
                let line = self.lines[id].as_mut().expect("an open line");
                if line.back() == Some(&end) {
                    line.push_back(new);
                } else {
                    line.push_front(new);
                }
                self.ends.insert(point_key(new), id);
                (id, false)
            }
            (Some(i), Some(j)) if i == j => {
                // Both ends of one line: it closes, repeating its first point last.
                let line = self.lines[i].as_mut().expect("an open line");
                let first = *line.front().expect("points");
                line.push_back(first);
                (i, true)
            }
            (Some(i), Some(j)) => {
                // Two lines joined by the segment: the shorter one moved onto the longer.
                let (len_i, len_j) = (self.lines[i].as_ref().map_or(0, |l| l.len()), self.lines[j].as_ref().map_or(0, |l| l.len()));
                let (keep, keep_end, other, other_end) = if len_i >= len_j { (i, a, j, b) } else { (j, b, i, a) };
                let mut moved = self.lines[other].take().expect("an open line");
                self.free.push(other);
                // `moved` runs from other_end to its far end.
                if moved.front() != Some(&other_end) {
                    moved.make_contiguous().reverse();
                }
                let far = *moved.back().expect("points");
                let line = self.lines[keep].as_mut().expect("an open line");
                if line.back() == Some(&keep_end) {
                    line.extend(moved);
                } else {
                    for p in moved {
                        line.push_front(p);
                    }
                }
                self.ends.insert(point_key(far), keep);
                (keep, false)
            }
        }
    }

    fn new_line(&mut self, points: std::collections::VecDeque<[f64; 2]>) -> usize {
        match self.free.pop() {
            Some(id) => {
                self.lines[id] = Some(points);
                id
            }
            None => {
                self.lines.push(Some(points));
                self.lines.len() - 1
            }
        }
    }

    /// Takes line `id` out (its ends forgotten).
    fn remove(&mut self, id: usize) -> std::collections::VecDeque<[f64; 2]> {
        let line = self.lines[id].take().expect("an open line");
        for end in [line.front(), line.back()].into_iter().flatten() {
            if self.ends.get(&point_key(*end)) == Some(&id) {
                self.ends.remove(&point_key(*end));
            }
        }
        self.free.push(id);
        line
    }

    /// Takes line `id` out if it is still open and both its ends lie above `lower_edge`.
    fn take_if_ended(&mut self, id: usize, lower_edge: f64) -> Option<std::collections::VecDeque<[f64; 2]>> {
        let line = self.lines.get(id)?.as_ref()?;
        let (front, back) = (line.front()?, line.back()?);
        (front[1] < lower_edge && back[1] < lower_edge).then(|| self.remove(id))
    }
}

/// The valid elevations' range where `levels` needs it (an interval), None otherwise.
fn range_for(src: &dyn HeightRows, levels: &Levels) -> Option<(f64, f64)> {
    matches!(levels, Levels::Interval { .. }).then(|| super::elevation_range(src)).flatten()
}

mod polygons;
pub use polygons::{contour_polygons, Band};

#[cfg(test)]
mod tests {
    use super::*;
    use volterra_formats::heightfield::{Crs, Heightfield};

    /// The batch join `contours` used before it joined lines as the rows are visited: every
    /// segment held, then joined into maximal lines through a map of end points (open lines
    /// from their ends first, then the closed loops left). Kept as the reference.
    fn join_segments(segs: &[[[f64; 2]; 2]]) -> Vec<Vec<[f64; 2]>> {
        let key = |p: [f64; 2]| (p[0].to_bits(), p[1].to_bits());
        // Each point meets at most two segment ends (marching squares' points have degree two).
        let mut at: HashMap<(u64, u64), Vec<usize>> = HashMap::with_capacity(segs.len() * 2);
        for (i, s) in segs.iter().enumerate() {
            for p in s {
                at.entry(key(*p)).or_default().push(i);
            }
        }
        let mut used = vec![false; segs.len()];
        let mut chains = Vec::new();
        let walk = |start: usize, from: [f64; 2], used: &mut Vec<bool>| {
            let mut chain = vec![from];
            let (mut seg, mut here) = (start, from);
            loop {
                used[seg] = true;
                let s = segs[seg];
                let next = if key(s[0]) == key(here) { s[1] } else { s[0] };
                chain.push(next);
                here = next;
                match at[&key(here)].iter().find(|&&j| !used[j]) {
                    Some(&j) => seg = j,
                    None => break,
                }
            }
            chain
        };
        // Open lines start at points with one segment end.
        for (i, s) in segs.iter().enumerate() {
            for p in s {
                if !used[i] && at[&key(*p)].len() == 1 {
                    chains.push(walk(i, *p, &mut used));
                }
            }
        }
        for i in 0..segs.len() {
            if !used[i] {
                chains.push(walk(i, segs[i][0], &mut used));
            }
        }
        chains
    }

    /// A heightfield's rows, counting the rows read; with `bad`, as a reader whose chunk
    /// under that row fails to decode: from then on `failure` says so (as `GeoTiffRows`
    /// does) and the row reads as NoData.
    struct CountedRows<'a> {
        hf: &'a Heightfield,
        bad: Option<usize>,
        read: std::sync::atomic::AtomicUsize,
        failed: std::sync::atomic::AtomicBool,
    }

    impl<'a> CountedRows<'a> {
        fn new(hf: &'a Heightfield, bad: Option<usize>) -> Self {
            CountedRows { hf, bad, read: Default::default(), failed: Default::default() }
        }
    }

    impl HeightRows for CountedRows<'_> {
        fn size(&self) -> [usize; 2] {
            self.hf.size()
        }
        fn cell_size(&self) -> [f64; 2] {
            self.hf.cell_size()
        }
        fn read_row(&self, row: usize, col: usize, out: &mut [f32]) {
            self.read.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            self.hf.read_row(row, col, out);
            if self.bad == Some(row) {
                self.failed.store(true, std::sync::atomic::Ordering::Relaxed);
                out.fill(f32::NAN);
            }
        }
        fn failure(&self) -> Option<String> {
            self.failed.load(std::sync::atomic::Ordering::Relaxed).then(|| "dem.tif: tile 7 could not be decoded".to_string())
        }
    }

    /// A row that cannot be read ends every pass over the rows there — the range, the lines,
    /// the polygons — and the error says why (not what a partial range makes of the
    /// levels), instead of coming after the rest of a large raster has been read.
    #[test]
    fn a_row_that_cannot_be_read_stops_the_passes_at_once() {
        let (w, h) = (40, 300);
        let hf = grid(w, h, |c, r| ((c as f64 / 5.0).sin() * 10.0 + r as f64 * 0.1) as f32);
        for bad in [0, 30] {
            let interval = Levels::Interval { interval: 2.0, offset: 0.0 };
            let fixed = Levels::Fixed(vec![-5.0, 0.0, 5.0]);
            for (levels, what) in [(&interval, "interval"), (&fixed, "fixed levels")] {
                let rows = CountedRows::new(&hf, Some(bad));
                let e = contours_each(&rows, &hf.georef(), levels, |_| Ok(())).unwrap_err();
                assert!(e.to_string().contains("tile 7 could not be decoded"), "{what}: {e}");
                let read = rows.read.into_inner();
                assert!(read <= bad + 1, "{what}, bad row {bad}: lines: {read} rows read");
                let rows = CountedRows::new(&hf, Some(bad));
                let e = contour_polygons(&rows, &hf.georef(), levels).unwrap_err();
                assert!(e.to_string().contains("tile 7 could not be decoded"), "{what}: {e}");
                let read = rows.read.into_inner();
                assert!(read <= bad + 1, "{what}, bad row {bad}: polygons: {read} rows read");
            }
            let rows = CountedRows::new(&hf, Some(bad));
            let _ = volterra_formats::heightfield::summarise(&rows);
            assert_eq!(rows.read.into_inner(), bad + 1, "the range pass");
        }
    }

    /// A line as a canonical list of point bits: an open line in the direction whose first
    /// point is smaller, a closed one from its smallest point in the smaller direction.
    fn canonical(points: &[[f64; 2]]) -> Vec<(u64, u64)> {
        let keys: Vec<(u64, u64)> = points.iter().map(|&p| point_key(p)).collect();
        if keys.len() > 2 && keys.first() == keys.last() {
            let ring = &keys[..keys.len() - 1];
            let start = (0..ring.len()).min_by_key(|&i| ring[i]).unwrap();
            let forward: Vec<_> = (0..ring.len()).map(|i| ring[(start + i) % ring.len()]).collect();
            let backward: Vec<_> = (0..ring.len()).map(|i| ring[(start + ring.len() - i) % ring.len()]).collect();
            forward.min(backward)
        } else {
            let reversed: Vec<_> = keys.iter().rev().copied().collect();
            keys.min(reversed)
        }
    }

    /// Lines joined as the rows are visited (and handed out as they end) are the lines the
    /// batch join makes of every segment held: on a rough DEM with NoData holes and
    /// saddles, at many levels, the same lines point for point.
    #[test]
    fn lines_joined_row_by_row_are_those_of_the_whole_raster_joined_at_once() {
        let mut x = 0x2545_f491_4f6c_dd1du64;
        let mut rand = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        let (w, h) = (83, 61);
        let noise: Vec<f64> = (0..w * h).map(|_| rand()).collect();
        let hf = grid(w, h, |c, r| {
            let hole = ((c as f64 - 20.0).powi(2) + (r as f64 - 30.0).powi(2)) < 40.0 || (c > 60 && r == 10);
            let smooth = 10.0 * ((c as f64) / 9.0).sin() * ((r as f64) / 7.0).cos();
            if hole {
                f32::NAN
            } else {
                (smooth + 4.0 * noise[r * w + c]) as f32
            }
        });
        let levels = Levels::Interval { interval: 1.5, offset: 0.25 };
        let mut streamed: Vec<(u64, Vec<(u64, u64)>)> = Vec::new();
        // Rows read when each line came out: the range pass reads all h first.
        let counted = CountedRows::new(&hf, None);
        let mut read_at_emission = Vec::new();
        contours_each(&counted, &hf.georef(), &levels, |l| {
            if !l.is_closed() {
                read_at_emission.push(counted.read.load(std::sync::atomic::Ordering::Relaxed) - h);
            }
            streamed.push((l.level.to_bits(), canonical(&l.points)));
            Ok(())
        })
        .unwrap();
        // Open lines come out once the rows below their ends are read, not all at the end:
        // a third of them before half the rows have been read.
        let early = read_at_emission.iter().filter(|&&r| r < h / 2).count();
        assert!(
            early * 3 > read_at_emission.len() && early > 20,
            "{early} of {} open lines out before row {}",
            read_at_emission.len(),
            h / 2
        );
        // The batch reference, from the same segments.
        let checked = checked_levels(range_for(&hf, &levels), &levels).unwrap();
        let mut segments: HashMap<i64, Vec<[[f64; 2]; 2]>> = HashMap::new();
        for_each_square(&hf, |sq, _, _| {
            let (min, max) = sq.value_range();
            for k in level_range(&checked, min, max) {
                sq.segments(level_value(&checked, k), &mut |a, b| {
                    if a != b {
                        segments.entry(k).or_default().push([a, b]);
                    }
                });
            }
        });
        let to_map = to_map(&hf.georef());
        let mut batch: Vec<(u64, Vec<(u64, u64)>)> = Vec::new();
        for (k, segs) in &segments {
            for chain in join_segments(segs) {
                let points: Vec<[f64; 2]> = chain.into_iter().map(&to_map).collect();
                batch.push((level_value(&checked, *k).to_bits(), canonical(&points)));
            }
        }
        let long = batch.iter().filter(|(_, l)| l.len() > 4).count();
        assert!(batch.len() > 300 && long > 100, "{} lines, {long} of more than four points", batch.len());
        streamed.sort();
        batch.sort();
        assert_eq!(streamed.len(), batch.len(), "line count");
        assert!(streamed == batch, "the lines differ");
    }

    fn grid(w: usize, h: usize, f: impl Fn(usize, usize) -> f32) -> Heightfield {
        Heightfield {
            width: w,
            height: h,
            cell_size: [1.0, 1.0],
            cell_size_native: [1.0, 1.0],
            origin: [0.0, 0.0],
            crs: Crs::local(),
            elevations: (0..w * h).map(|i| f(i % w, i / w)).collect(),
            nodata: Default::default(),
            nodata_value: None,
            notes: vec![],
            attributes: vec![],
            units: volterra_formats::heightfield::GridUnits::METRES,
        }
    }

    /// A cone: each level's line is one closed loop, every vertex at the level's radius
    /// up to the linear interpolation's chord error.
    #[test]
    fn a_cone_gives_one_closed_ring_per_level() {
        let (n, c) = (41, 20.0);
        let hf = grid(n, n, |x, y| 100.0 - ((x as f32 - c).powi(2) + (y as f32 - c).powi(2)).sqrt());
        let lines = contours(&hf, &hf.georef(), &Levels::Interval { interval: 5.0, offset: 0.0 }).unwrap();
        // Levels 85…95 lie wholly inside the raster (radius 15…5 < 20).
        for level in [85.0, 90.0, 95.0] {
            let rings: Vec<_> = lines.iter().filter(|l| l.level == level).collect();
            assert_eq!(rings.len(), 1, "level {level}");
            assert!(rings[0].is_closed());
            let r = 100.0 - level;
            for p in &rings[0].points {
                // Map coordinates: x = col, y = −row (origin at cell (0, 0)'s centre).
                let d = ((p[0] - c as f64).powi(2) + (-p[1] - c as f64).powi(2)).sqrt();
                assert!((d - r).abs() < 0.08 * r / 5.0 + 0.02, "level {level}: vertex at radius {d}");
            }
        }
    }

    /// A ramp crossing the whole raster: open lines from edge to edge, reaching half a cell
    /// beyond the outer centres; a value equal to the level counts as above it.
    #[test]
    fn a_ramp_gives_straight_lines_to_the_raster_edge() {
        let hf = grid(6, 4, |x, _| x as f32 * 10.0);
        let lines = contours(&hf, &hf.georef(), &Levels::Fixed(vec![15.0, 20.0])).unwrap();
        assert_eq!(lines.len(), 2);
        let l15 = lines.iter().find(|l| l.level == 15.0).unwrap();
        assert!(!l15.is_closed());
        let ys: Vec<f64> = l15.points.iter().map(|p| p[1]).collect();
        // 15 is the edge's mid value: nudged as GDAL does, the line sits 1e-7 of a cell off.
        assert!(l15.points.iter().all(|p| (p[0] - 1.5).abs() < 1e-6), "{:?}", l15.points);
        let (lo, hi) = ys.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &y| (a.min(y), b.max(y)));
        assert_eq!((lo, hi), (-3.5, 0.5), "from the south edge to the north edge");
        // 20 is column 2's value: nudged up, the line passes 1e-7 of a cell west of it.
        let l20 = lines.iter().find(|l| l.level == 20.0).unwrap();
        assert!(l20.points.iter().all(|p| (p[0] - 2.0).abs() < 1e-6 && p[0] < 2.0));
    }

    /// NoData: lines stop half-way between a valid and a NoData centre; a level outside
    /// the data draws nothing; a wrong interval is refused.
    #[test]
    fn lines_stop_at_nodata_and_bad_levels_are_refused() {
        let mut hf = grid(5, 5, |x, _| x as f32);
        hf.nodata = (0..25).map(|i| i % 5 == 4 && i / 5 == 2).collect();
        hf.elevations[14] = f32::NAN;
        let lines = contours(&hf, &hf.georef(), &Levels::Fixed(vec![2.5])).unwrap();
        assert_eq!(lines.len(), 1, "2.5 lies between columns 2 and 3, away from the hole");
        let lines = contours(&hf, &hf.georef(), &Levels::Fixed(vec![3.5])).unwrap();
        assert_eq!(lines.len(), 2, "3.5 is cut by the NoData cell at column 4: {lines:?}");
        assert!(contours(&hf, &hf.georef(), &Levels::Fixed(vec![50.0])).unwrap().is_empty());
        assert!(contours(&hf, &hf.georef(), &Levels::Interval { interval: 0.0, offset: 0.0 }).is_err());
        assert!(contours(&hf, &hf.georef(), &Levels::Interval { interval: 1e-9, offset: 0.0 }).is_err());
        assert!(contours(&hf, &hf.georef(), &Levels::Fixed(vec![f64::NAN])).is_err());
    }

    /// Twice a ring's signed area about its first vertex.
    fn area2(r: &[[f64; 2]]) -> f64 {
        let o = r[0];
        r.windows(2).map(|w| (w[0][0] - o[0]) * (w[1][1] - o[1]) - (w[1][0] - o[0]) * (w[0][1] - o[1])).sum()
    }

    /// A band's area: its outer rings less their holes (map units).
    fn band_area(b: &Band) -> f64 {
        b.polygons.iter().map(|p| area2(&p[0]) / 2.0 + p[1..].iter().map(|h| area2(h) / 2.0).sum::<f64>()).sum()
    }

    /// The bands partition the raster: their areas add up to its extent (half a cell
    /// beyond the outer centres), outer rings run counter-clockwise and holes clockwise,
    /// every ring is closed, and each band's bounds are its levels (the data's extremes at
    /// the ends). Hard cases: a checkerboard of saddles (rings touching at points), and a
    /// centre equal to a level (a ring 1e-7 of a cell across, far from the origin).
    #[test]
    fn contour_polygons_partition_the_raster() {
        let cases: Vec<(Heightfield, Levels)> = vec![
            (
                grid(41, 41, |x, y| 100.0 - ((x as f32 - 20.0).powi(2) + (y as f32 - 20.0).powi(2)).sqrt()),
                Levels::Interval { interval: 5.0, offset: 0.0 },
            ),
            (grid(9, 8, |x, y| if (x + y) % 2 == 0 { 10.0 } else { 0.0 }), Levels::Fixed(vec![5.0])),
            (grid(7, 6, |x, y| if (x, y) == (3, 2) { 180.0 } else { 170.0 + x as f32 }), Levels::Interval { interval: 10.0, offset: 0.0 }),
        ];
        for (n, (mut hf, levels)) in cases.into_iter().enumerate() {
            hf.origin = [5.0e5, 4.2e6];
            let bands = contour_polygons(&hf, &hf.georef(), &levels).unwrap();
            let total: f64 = bands.iter().map(band_area).sum();
            let extent = (hf.width * hf.height) as f64;
            assert!((total - extent).abs() < 1e-6 * extent, "case {n}: the bands cover {total}, the raster {extent}");
            for b in &bands {
                assert!(b.min < b.max, "case {n}: band {}…{}", b.min, b.max);
                for p in &b.polygons {
                    assert!(area2(&p[0]) > 0.0, "case {n}: an outer ring runs clockwise");
                    assert!(p[1..].iter().all(|h| area2(h) < 0.0), "case {n}: a hole runs counter-clockwise");
                    assert!(p.iter().all(|r| r.len() >= 4 && r.first() == r.last()), "case {n}: a ring is not closed");
                }
            }
        }
        // The cone: the band 85…90 is an annulus between radii 10 and 15 cells.
        let hf = grid(41, 41, |x, y| 100.0 - ((x as f32 - 20.0).powi(2) + (y as f32 - 20.0).powi(2)).sqrt());
        let bands = contour_polygons(&hf, &hf.georef(), &Levels::Interval { interval: 5.0, offset: 0.0 }).unwrap();
        let annulus = bands.iter().find(|b| b.min == 85.0).unwrap();
        assert_eq!((annulus.max, annulus.polygons.len(), annulus.polygons[0].len()), (90.0, 1, 2), "one polygon with one hole");
        let want = std::f64::consts::PI * (15.0f64.powi(2) - 10.0f64.powi(2));
        assert!((band_area(annulus) - want).abs() < 0.01 * want, "annulus area {} against {want}", band_area(annulus));
        // The ends: the lowest band starts at the lowest elevation, a fixed list's highest
        // ends at the highest.
        let bands = contour_polygons(&hf, &hf.georef(), &Levels::Fixed(vec![90.0])).unwrap();
        let lowest = hf.elevations.iter().fold(f32::INFINITY, |a, &b| a.min(b)) as f64;
        assert_eq!((bands[0].min, bands[0].max, bands[1].min, bands[1].max), (lowest, 90.0, 90.0, 100.0));
        // The centre equal to a level: a tiny diamond in the band above, a hole below.
        let hf = grid(7, 6, |x, y| if (x, y) == (3, 2) { 180.0 } else { 170.0 + x as f32 });
        let bands = contour_polygons(&hf, &hf.georef(), &Levels::Interval { interval: 10.0, offset: 0.0 }).unwrap();
        let top = bands.iter().find(|b| b.min == 180.0).unwrap();
        assert_eq!(top.polygons.len(), 1);
        assert!(band_area(top) > 0.0 && band_area(top) < 1e-12, "{}", band_area(top));
    }
}
