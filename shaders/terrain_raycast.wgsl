// Per-pixel terrain ray casting over the max-quadtree (Park, Oh & Cho; pyramidal
// displacement mapping with the lid map and exact bilinear patches).
//
// Grid space (see src/render/terrain/grid.rs): sample (i, j) at (i, j), j north, z in
// metres relative to the middle of the elevation range; the ray parameter t is the world
// distance. Pyramid level L, node (a, b) covers patches [a·2^L, (a+1)·2^L) on each axis
// and holds the highest lid over them.

const HOLE: f32 = -3.0e38;
const BIG: f32 = 3.0e38;
// Heights below this are NoData (uploaded as HOLE).
const NODATA_BELOW: f32 = -1.0e37;

struct Params {
    // w: 1 = parallel projection (xyz unused: every position is relative to the eye).
    eye: vec4<f32>,
    // Images of the camera's forward / right / up unit vectors in grid space;
    // w: half width, half height (of the view plane at distance 1, or in world units when
    // parallel), ambient.
    fwd: vec4<f32>,
    right: vec4<f32>,
    up: vec4<f32>,
    // Rows of the matrix that takes a local normal (metres) to world space.
    normal_x: vec4<f32>,
    normal_y: vec4<f32>,
    normal_z: vec4<f32>,
    // z_lo, z_hi (valid heights, relative to the eye), cell size east, north (metres).
    extent: vec4<f32>,
    // width, height (pixels), cells east, cells north.
    size: vec4<u32>,
    // top level, step cap, traversal (0 quadtree, 1 quadtree without the raise, 2 linear),
    // flags (1 shadows, 2 texture, 4 smooth normals, 8 the pyramid's texel pairs east-west).
    control: vec4<u32>,
    // number of lights; shadow lift (metres, as f32 bits); rays per pixel side; tiles per
    // texture array (SPLIT).
    misc: vec4<u32>,
    // The eye (perspective) or the view plane's centre (parallel) in grid space, as a
    // two-float sum hi + lo per axis. The shader works relative to it: near the eye —
    // where a walk-through looks — positions and heights are small numbers and f32 keeps
    // their differences to a fraction of a millimetre. (Absolute f32 positions lose
    // 1e-4 of a 30 m cell at x = 500 cells, which on a slope moves an eye 2 m above the
    // ground by 2e-4 of its height.)
    eye_hi: vec4<f32>,
    eye_lo: vec4<f32>,
    // Where the drape lies: texture coordinates s = x + y·gx, t = z + w·gy of grid point
    // (gx, gy) (LinearTexture::placement in shading.rs).
    drape: vec4<f32>,
    // Tiling (gpu.rs, Tiling::params): patches per tile, tiles east, k = log2 of the
    // patches per tile (31 when not tiled), tiles north.
    tiles: vec4<u32>,
    // Per light: unit direction toward it (world), the same in grid space, colour × intensity.
    light_world: array<vec4<f32>, 4>,
    light_grid: array<vec4<f32>, 4>,
    light_color: array<vec4<f32>, 4>,
    // The elevation colour table (linear RGB), low to high.
    ramp: array<vec4<f32>, 256>,
}

@group(0) @binding(0) var<uniform> P: Params;
// The samples and each tile's pyramid, one tile per layer (one layer when not tiled), and
// the pyramid's levels above the tiles (gpu.rs, Tiling).
@group(0) @binding(1) var heights: texture_2d_array<f32>;
@group(0) @binding(2) var pyramid: texture_2d_array<u32>;
@group(0) @binding(3) var colour_map: texture_2d<f32>;
@group(0) @binding(4) var colour_sampler: sampler;
@group(0) @binding(5) var<storage, read_write> out_colour: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> out_depth: array<f32>;
@group(0) @binding(7) var<storage, read_write> out_steps: array<u32>;
// [0]: rays that hit the step cap.
@group(0) @binding(8) var<storage, read_write> counters: array<atomic<u32>, 4>;
@group(0) @binding(9) var pyramid_top: texture_2d<f32>;
// Tiles beyond one texture array's bytes (gpu.rs, Tiling::layers_per_array, P.misc.w
// layers each): the heights' and the pyramids' further arrays. SPLIT (a pipeline
// constant) is false for every heightfield that fits one array, so their reads compile to
// the single array's load, no branch.
override SPLIT: bool = false;
@group(0) @binding(10) var heights1: texture_2d_array<f32>;
@group(0) @binding(11) var heights2: texture_2d_array<f32>;
@group(0) @binding(12) var heights3: texture_2d_array<f32>;
@group(0) @binding(13) var pyramid1: texture_2d_array<u32>;
@group(0) @binding(14) var pyramid2: texture_2d_array<u32>;
@group(0) @binding(15) var pyramid3: texture_2d_array<u32>;

// The texture array of tile `tile` and its layer there (split heightfields).
fn split_tile(tile: i32) -> vec2<i32> {
    let per = i32(P.misc.w);
    return vec2<i32>(tile / per, tile % per);
}

// Texel l of tile `tile`'s heights.
fn load_height(l: vec2<i32>, tile: i32) -> f32 {
    if !SPLIT {
        return textureLoad(heights, l, tile, 0).r;
    }
    let at = split_tile(tile);
    let k = at.y;
    switch at.x {
        case 0: { return textureLoad(heights, l, k, 0).r; }
        case 1: { return textureLoad(heights1, l, k, 0).r; }
        case 2: { return textureLoad(heights2, l, k, 0).r; }
        default: { return textureLoad(heights3, l, k, 0).r; }
    }
}

// The four corners l, l + (1, 0), l + (0, 1), l + (1, 1) of tile `tile`'s heights.
fn load_corners(l: vec2<i32>, tile: i32) -> vec4<f32> {
    if !SPLIT {
        return corners_of(heights, l, tile);
    }
    let at = split_tile(tile);
    let k = at.y;
    switch at.x {
        case 0: { return corners_of(heights, l, k); }
        case 1: { return corners_of(heights1, l, k); }
        case 2: { return corners_of(heights2, l, k); }
        default: { return corners_of(heights3, l, k); }
    }
}

fn corners_of(t: texture_2d_array<f32>, l: vec2<i32>, layer: i32) -> vec4<f32> {
    return vec4<f32>(
        textureLoad(t, l, layer, 0).r,
        textureLoad(t, l + vec2<i32>(1, 0), layer, 0).r,
        textureLoad(t, l + vec2<i32>(0, 1), layer, 0).r,
        textureLoad(t, l + vec2<i32>(1, 1), layer, 0).r,
    );
}

// Texel n of mip m of tile `tile`'s pyramid: two half floats (rounded up) to a texel,
// neighbours east-west where flag 8 is set, else north-south (terrain_pyramid.wgsl).
fn load_lid(n: vec2<i32>, tile: i32, m: i32) -> f32 {
    let east = (P.control.w & 8u) != 0u;
    let t = select(vec2<i32>(n.x, n.y >> 1u), vec2<i32>(n.x >> 1u, n.y), east);
    let pair = unpack2x16float(load_pair(t, tile, m));
    return select(pair.x, pair.y, (select(n.y, n.x, east) & 1) == 1);
}

fn load_pair(t: vec2<i32>, tile: i32, m: i32) -> u32 {
    if !SPLIT {
        return textureLoad(pyramid, t, tile, m).r;
    }
    let at = split_tile(tile);
    let k = at.y;
    switch at.x {
        case 0: { return textureLoad(pyramid, t, k, m).r; }
        case 1: { return textureLoad(pyramid1, t, k, m).r; }
        case 2: { return textureLoad(pyramid2, t, k, m).r; }
        default: { return textureLoad(pyramid3, t, k, m).r; }
    }
}

// The stored height of sample c (grid space). Tiles hold 2^k patches and share their
// border samples: the sample at a border is read from the tile east (north) of it, except
// past the last tile. Not tiled, k = 31 and every sample is in tile 0 (no branch: a
// branch on the tiling costs software rasterisers both paths).
fn height_at(c: vec2<i32>) -> f32 {
    let k = vec2<u32>(P.tiles.z);
    let tile = min(c >> k, vec2<i32>(i32(P.tiles.y), i32(P.tiles.w)) - 1);
    return load_height(c - (tile << k), tile.y * i32(P.tiles.y) + tile.x);
}

// The lid of quadtree node `node` at `level` ≥ 1 (level 0, the lid map, is not stored:
// `trace` takes it from the patch's heights): in its tile's pyramid below level k (tiles
// of 2^k patches; the pyramid's mip m is level m + 1), in the texture over the tiles from
// level k up (never, not tiled: k = 31).
fn lid(node: vec2<i32>, level: u32) -> f32 {
    let k = P.tiles.z;
    if level >= k {
        return textureLoad(pyramid_top, node, i32(level - k)).r;
    }
    let shift = vec2<u32>(k - level);
    let tile = node >> shift;
    return load_lid(node - (tile << shift), tile.y * i32(P.tiles.y) + tile.x, i32(level) - 1);
}

struct Hit {
    t: f32,
    u: f32,
    v: f32,
    steps: u32,
    cell: vec2<i32>,
    found: bool,
    capped: bool,
}

// Part [t0, t1] (t0 ≥ 0) of the ray inside the terrain's box; t0 > t1 when it misses.
fn clip(o: vec3<f32>, d: vec3<f32>) -> vec2<f32> {
    // The z slab is widened a little: a ray grazing the highest peak must not be clipped
    // by f32 rounding of the box test.
    let pad = 1e-4 * max(1.0, P.extent.y - P.extent.x);
    let lo = vec3<f32>(from_eye_xy(vec2<f32>(0.0)), P.extent.x - pad);
    let hi = vec3<f32>(from_eye_xy(vec2<f32>(P.size.zw)), P.extent.y + pad);
    var t0 = 0.0;
    var t1 = BIG;
    for (var k = 0; k < 3; k++) {
        if d[k] == 0.0 {
            if o[k] < lo[k] || o[k] > hi[k] {
                return vec2<f32>(1.0, 0.0);
            }
        } else {
            let a = (lo[k] - o[k]) / d[k];
            let b = (hi[k] - o[k]) / d[k];
            t0 = max(t0, min(a, b));
            t1 = min(t1, max(a, b));
        }
    }
    return vec2<f32>(t0, t1);
}

// A stored height (relative to the tile's middle) relative to the eye instead. The
// first subtraction is exact for heights near the eye's (Sterbenz), and each step is
// monotonic, so lid bounds stay bounds.
fn from_eye(h: f32) -> f32 {
    return (h - P.eye_hi.z) - P.eye_lo.z;
}

// A grid position (x, y in cells) relative to the eye; exact near it, as above.
fn from_eye_xy(g: vec2<f32>) -> vec2<f32> {
    return (g - P.eye_hi.xy) - P.eye_lo.xy;
}

// z00, z10, z01, z11 of patch c, relative to the eye. A patch lies in one tile, its east
// and north corners included (tiles share their border samples), so the tile is found
// once for the four loads (the traversal reads every level-0 node's corners).
fn patch_heights(c: vec2<i32>) -> vec4<f32> {
    let k = vec2<u32>(P.tiles.z);
    let tile = min(c >> k, vec2<i32>(i32(P.tiles.y), i32(P.tiles.w)) - 1);
    let l = c - (tile << k);
    let layer = tile.y * i32(P.tiles.y) + tile.x;
    let z = load_corners(l, layer);
    return vec4<f32>(from_eye(z.x), from_eye(z.y), from_eye(z.z), from_eye(z.w));
}

// The stored height of sample c, or HOLE beyond the grid's edge.
fn height_or_hole(c: vec2<i32>) -> f32 {
    let last = vec2<i32>(i32(P.size.z), i32(P.size.w));
    if any(c < vec2<i32>(0)) || any(c > last) {
        return HOLE;
    }
    return height_at(c);
}

// A sample's height difference along one axis (metres per cell) from the heights below, at
// and above it: central, one-sided where a neighbour is NoData or beyond the edge, 0 where
// both are (the rule of TerrainGrid::sample_gradient).
fn axis_difference(z_down: f32, z: f32, z_up: f32) -> f32 {
    let has_up = z_up > -1.0e38;
    let has_down = z_down > -1.0e38;
    if has_up && has_down {
        return 0.5 * (z_up - z_down);
    } else if has_up {
        return z_up - z;
    } else if has_down {
        return z - z_down;
    }
    return 0.0;
}

// The shading normal's local form (east, north, up; not unit) at (u, v) in patch c: the
// corner samples' gradients (metres per metre) interpolated bilinearly, so that normals
// are continuous across patch borders (no facets) while the intersection stays the exact
// bilinear patch's. The four gradients share their samples: the corners and their eight
// neighbours along the axes are read once each (12 reads; a gradient at a time read 20).
fn smooth_local_normal(c: vec2<i32>, u: f32, v: f32) -> vec3<f32> {
    let z00 = height_or_hole(c);
    let z10 = height_or_hole(c + vec2<i32>(1, 0));
    let z01 = height_or_hole(c + vec2<i32>(0, 1));
    let z11 = height_or_hole(c + vec2<i32>(1, 1));
    let g00 = vec2<f32>(axis_difference(height_or_hole(c + vec2<i32>(-1, 0)), z00, z10), axis_difference(height_or_hole(c + vec2<i32>(0, -1)), z00, z01));
    let g10 = vec2<f32>(axis_difference(z00, z10, height_or_hole(c + vec2<i32>(2, 0))), axis_difference(height_or_hole(c + vec2<i32>(1, -1)), z10, z11));
    let g01 = vec2<f32>(axis_difference(height_or_hole(c + vec2<i32>(-1, 1)), z01, z11), axis_difference(z00, z01, height_or_hole(c + vec2<i32>(0, 2))));
    let g11 = vec2<f32>(axis_difference(z01, z11, height_or_hole(c + vec2<i32>(2, 1))), axis_difference(z10, z11, height_or_hole(c + vec2<i32>(1, 2))));
    let cell = P.extent.zw;
    let g = mix(mix(g00 / cell, g10 / cell, u), mix(g01 / cell, g11 / cell, u), v);
    return vec3<f32>(-g.x, -g.y, 1.0);
}

// First s in [0, len] where (u0, v0, z0) + s·d meets the patch from above; −1 if none.
// f(s) = a s² + b s + c is the ray's height above the patch; stable roots q/a and c/q
// (see intersect_patch in grid.rs for the derivation and the edge rules).
// Starting below the surface is a hit at 0: the terrain is a solid (an eye under the
// ground, a ray entering through a side of the box, rounding at a shared edge, or a ray
// that went under the surface through a NoData void and meets the void's wall here).
fn intersect_patch(z: vec4<f32>, u0: f32, v0: f32, z0: f32, d: vec3<f32>, len: f32) -> f32 {
    let pa = z.w - z.y - z.z + z.x;
    let pb = z.y - z.x;
    let pc = z.z - z.x;
    let c = z0 - (z.x + pb * u0 + pc * v0 + pa * u0 * v0);
    let b = d.z - pb * d.x - pc * d.y - pa * (u0 * d.y + v0 * d.x);
    let a = -pa * d.x * d.y;
    if c < 0.0 {
        return 0.0;
    }
    if c == 0.0 && (b < 0.0 || (b == 0.0 && a <= 0.0)) {
        return 0.0;
    }
    // A root a hair past the far edge still belongs here (f32: a relative 1e-4 of the
    // segment), so that no ray slips through the edge two cells share.
    let limit = len * 1.0001 + 1e-7;
    var s = BIG;
    if a == 0.0 {
        if b < 0.0 {
            s = -c / b;
        }
    } else {
        let disc = b * b - 4.0 * a * c;
        if disc < 0.0 {
            return -1.0;
        }
        let q = -0.5 * (b + select(-1.0, 1.0, b >= 0.0) * sqrt(disc));
        let r1 = q / a;
        if r1 >= 0.0 {
            s = r1;
        }
        if q != 0.0 {
            let r2 = c / q;
            if r2 >= 0.0 {
                s = min(s, r2);
            }
        }
    }
    if s <= limit {
        return min(s, len);
    }
    return -1.0;
}

// The node index along one axis containing p at a level whose nodes are `size` cells wide;
// on a node border, the node the ray goes into.
fn node_index(p: f32, d: f32, size: f32, count: i32) -> i32 {
    let s = p / size;
    var f = floor(s);
    if f == s && d < 0.0 {
        f -= 1.0;
    }
    return clamp(i32(f), 0, count - 1);
}

fn node_count(level: u32) -> vec2<i32> {
    let cells = P.size.zw;
    let n = (cells + vec2<u32>((1u << level) - 1u)) >> vec2<u32>(level);
    return vec2<i32>(n);
}

// Which child (0 or 1) along one axis the ray is in at time t. Decided by comparing t
// with the time the ray crosses the midline — the same expression that gives the child's
// exit — and not by the rounded position: a child chosen by position can lie behind the
// ray, exit at once, and be chosen again after the raise, forever.
fn child_bit(t: f32, o: f32, d: f32, mid: f32) -> i32 {
    if d == 0.0 {
        return select(0, 1, o >= mid);
    }
    let t_mid = (mid - o) / d;
    if d > 0.0 {
        return select(0, 1, t >= t_mid);
    }
    return select(1, 0, t >= t_mid);
}

// The first hit of o + t·d, t ∈ [t_start, t_end]. Descends on a possible hit, and after a
// miss leaves the node through its exit face and (traversal 0) goes up one level. Node
// indices only ever move in the ray's direction, so the walk cannot stall or loop; the
// step cap is a guard whose hits are counted.
fn trace(o: vec3<f32>, d: vec3<f32>, t_start: f32, t_end: f32) -> Hit {
    var h: Hit;
    h.found = false;
    h.capped = false;
    h.steps = 0u;
    h.t = t_end;
    let top = P.control.x;
    let cap = P.control.y;
    let mode = P.control.z;
    var level = top;
    if mode == 2u {
        level = 0u;
    }
    var t = t_start;
    var size = f32(1u << level);
    var count = node_count(level);
    let p0 = o + t * d + P.eye_hi.xyz;
    var node = vec2<i32>(node_index(p0.x, d.x, size, count.x), node_index(p0.y, d.y, size, count.y));
    let step = vec2<i32>(select(-1, 1, d.x > 0.0), select(-1, 1, d.y > 0.0));
    loop {
        if h.steps >= cap {
            h.capped = true;
            break;
        }
        h.steps += 1u;
        size = f32(1u << level);
        count = node_count(level);
        if node.x < 0 || node.y < 0 || node.x >= count.x || node.y >= count.y {
            break;
        }
        let lo = from_eye_xy(vec2<f32>(node) * size);
        let hi = from_eye_xy(vec2<f32>(node + 1) * size);
        var tx = BIG;
        if d.x > 0.0 {
            tx = (hi.x - o.x) / d.x;
        } else if d.x < 0.0 {
            tx = (lo.x - o.x) / d.x;
        }
        var ty = BIG;
        if d.y > 0.0 {
            ty = (hi.y - o.y) / d.y;
        } else if d.y < 0.0 {
            ty = (lo.y - o.y) / d.y;
        }
        let t_exit = max(min(min(tx, ty), t_end), t);
        // Level 0: the patch's lid from its four heights (HOLE where one is NoData).
        var z = vec4<f32>(HOLE);
        var zmax: f32;
        if level == 0u {
            z = patch_heights(node);
            zmax = max(max(z.x, z.y), max(z.z, z.w));
            if min(min(z.x, z.y), min(z.z, z.w)) <= from_eye(NODATA_BELOW) {
                zmax = HOLE;
            }
        } else {
            zmax = from_eye(lid(node, level));
        }
        let z_in = o.z + t * d.z;
        let z_out = o.z + t_exit * d.z;
        if min(z_in, z_out) <= zmax {
            if level == 0u {
                let pa = o + t * d;
                let u0 = pa.x - lo.x;
                let v0 = pa.y - lo.y;
                let s = intersect_patch(z, u0, v0, pa.z, d, t_exit - t);
                if s >= 0.0 {
                    h.found = true;
                    h.t = t + s;
                    h.cell = node;
                    h.u = clamp(u0 + s * d.x, 0.0, 1.0);
                    h.v = clamp(v0 + s * d.y, 0.0, 1.0);
                    break;
                }
            } else {
                // Nothing in this node reaches above zmax: a downward ray can skip to
                // where it crosses that plane before choosing the child.
                if d.z < 0.0 && z_in > zmax {
                    t = clamp((zmax - o.z) / d.z, t, t_exit);
                }
                level -= 1u;
                let mid = from_eye_xy((vec2<f32>(node) + 0.5) * size);
                node = node * 2 + vec2<i32>(child_bit(t, o.x, d.x, mid.x), child_bit(t, o.y, d.y, mid.y));
                continue;
            }
        }
        // Missed this node: move to its exit face and into the neighbour.
        if t_exit >= t_end {
            break;
        }
        t = t_exit;
        // Did the step leave the parent node? (Into the sibling, the parent — already
        // found possibly hit — has nothing new to say, and re-testing it costs a step.)
        var left_parent: bool;
        if tx <= ty {
            node.x += step.x;
            left_parent = (node.x & 1) == select(1, 0, step.x > 0);
        } else {
            node.y += step.y;
            left_parent = (node.y & 1) == select(1, 0, step.y > 0);
        }
        if mode == 0u && level < top && left_parent {
            level += 1u;
            node = node >> vec2<u32>(1u);
        }
    }
    return h;
}

// The elevation colour at normalised elevation f: linear between the 256 entries of the
// colour table (shading::elevation_colour).
fn elevation_colour(f_in: f32) -> vec3<f32> {
    let x = clamp(f_in, 0.0, 1.0) * 255.0;
    let i = min(u32(floor(x)), 254u);
    let s = x - f32(i);
    return mix(P.ramp[i].rgb, P.ramp[i + 1u].rgb, s);
}

struct Sample {
    colour: vec4<f32>,
    depth: f32,
    steps: u32,
}

// The ray through image point (px, py) (pixels from the top-left corner): its colour
// (alpha 1 on a hit, all 0 on a miss), depth (−1 on a miss) and traversal steps.
fn cast_ray(px: f32, py: f32) -> Sample {
    let sx = (2.0 * px / f32(P.size.x) - 1.0) * P.fwd.w;
    let sy = (1.0 - 2.0 * py / f32(P.size.y)) * P.right.w;
    var o = P.eye.xyz;
    var d = P.fwd.xyz;
    if P.eye.w > 0.5 {
        o = o + P.right.xyz * sx + P.up.xyz * sy;
    } else {
        d = (P.fwd.xyz + P.right.xyz * sx + P.up.xyz * sy) / sqrt(1.0 + sx * sx + sy * sy);
    }
    var colour = vec4<f32>(0.0);
    var depth = -1.0;
    var steps = 0u;
    let range = clip(o, d);
    if range.x <= range.y {
        let h = trace(o, d, range.x, range.y);
        steps = h.steps;
        if h.capped {
            atomicAdd(&counters[0], 1u);
        }
        if h.found {
            depth = h.t;
            let z = patch_heights(h.cell);
            let pa = z.w - z.y - z.z + z.x;
            let pb = z.y - z.x;
            let pc = z.z - z.x;
            let zh = z.x + pb * h.u + pc * h.v + pa * h.u * h.v;
            let gx = f32(h.cell.x) + h.u;
            let gy = f32(h.cell.y) + h.v;
            var base: vec3<f32>;
            let ray_z = o.z + h.t * d.z;
            if zh - ray_z > 1e-3 * max(P.extent.y - P.extent.x, 1.0) {
                // The ray came in below the surface — through a side of the box, or under
                // the ground through a NoData void — and meets the solid's side where it
                // enters this cell: a wall of soil (WALL_COLOUR in reference.rs) facing
                // out of the cell edge nearest the hit.
                var face = vec3<f32>(-1.0, 0.0, 0.0);
                var dist = h.u;
                if 1.0 - h.u < dist {
                    dist = 1.0 - h.u;
                    face = vec3<f32>(1.0, 0.0, 0.0);
                }
                if h.v < dist {
                    dist = h.v;
                    face = vec3<f32>(0.0, -1.0, 0.0);
                }
                if 1.0 - h.v < dist {
                    face = vec3<f32>(0.0, 1.0, 0.0);
                }
                let wn = normalize(vec3<f32>(dot(P.normal_x.xyz, face), dot(P.normal_y.xyz, face), dot(P.normal_z.xyz, face)));
                var we = vec3<f32>(P.up.w);
                for (var k = 0u; k < P.misc.x; k++) {
                    we += P.light_color[k].rgb * max(dot(wn, P.light_world[k].xyz), 0.0);
                }
                return Sample(vec4<f32>(vec3<f32>(0.20, 0.14, 0.09) * we, 1.0), depth, steps);
            }
            base = elevation_colour((zh - P.extent.x) / max(P.extent.y - P.extent.x, 1e-9));
            if (P.control.w & 2u) != 0u {
                // The drape, premultiplied over the elevation colour, where it covers the hit.
                let st = vec2<f32>(P.drape.x + P.drape.y * gx, P.drape.z + P.drape.w * gy);
                if all(st >= vec2<f32>(0.0)) && all(st <= vec2<f32>(1.0)) {
                    let texel = textureSampleLevel(colour_map, colour_sampler, st, 0.0);
                    base = texel.rgb + (1.0 - texel.a) * base;
                }
            }
            // The patch's own (faceted) normal, and the shading normal (smooth, or the same).
            let face_local = vec3<f32>(-(pb + pa * h.v) / P.extent.z, -(pc + pa * h.u) / P.extent.w, 1.0);
            let face_n = normalize(vec3<f32>(dot(P.normal_x.xyz, face_local), dot(P.normal_y.xyz, face_local), dot(P.normal_z.xyz, face_local)));
            var n = face_n;
            if (P.control.w & 4u) != 0u {
                let local_n = smooth_local_normal(h.cell, h.u, h.v);
                n = normalize(vec3<f32>(dot(P.normal_x.xyz, local_n), dot(P.normal_y.xyz, local_n), dot(P.normal_z.xyz, local_n)));
            }
            var e = vec3<f32>(P.up.w);
            // The shadow ray starts this far above the hit: the fixed lift (1e-3 of a cell),
            // plus four times the f32 rounding of the surface's height at the hit — its
            // height relative to the eye, and its position relative to the eye times the
            // patch's slope (metres per cell). Without the second term, a steep patch far
            // from the eye can start its shadow ray below itself and shadow itself (acne).
            let rel = abs(from_eye_xy(vec2<f32>(h.cell)) + vec2<f32>(h.u, h.v));
            let rounding = 5.96e-8 * (abs(zh) + abs(pb + pa * h.v) * rel.x + abs(pc + pa * h.u) * rel.y);
            let lift = bitcast<f32>(P.misc.y) + 4.0 * rounding;
            for (var k = 0u; k < P.misc.x; k++) {
                let cosine = dot(n, P.light_world[k].xyz);
                if cosine > 0.0 {
                    var lit = true;
                    if (P.control.w & 1u) != 0u && dot(face_n, P.light_world[k].xyz) <= 0.0 {
                        // The surface itself faces away from the light (where a smooth
                        // normal still leans toward it): in its own shadow.
                        lit = false;
                    } else if (P.control.w & 1u) != 0u {
                        let so = vec3<f32>(from_eye_xy(vec2<f32>(h.cell)) + vec2<f32>(h.u, h.v), zh + lift);
                        let sd = P.light_grid[k].xyz;
                        let sr = clip(so, sd);
                        if sr.x <= sr.y {
                            lit = !trace(so, sd, sr.x, sr.y).found;
                        }
                    }
                    if lit {
                        e += P.light_color[k].rgb * cosine;
                    }
                }
            }
            colour = vec4<f32>(base * e, 1.0);
        }
    }
    return Sample(colour, depth, steps);
}

// k × k rays per pixel (k = misc.z) on a stratified grid, their colours averaged (misses
// count as transparent black, so alpha is the coverage); depth and steps are those of the
// ray through the pixel's centre (one of the k² when k is odd, an extra ray when even).
@compute @workgroup_size(8, 8)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let width = P.size.x;
    let height = P.size.y;
    if id.x >= width || id.y >= height {
        return;
    }
    let pixel = id.y * width + id.x;
    let k = max(P.misc.z, 1u);
    let mid = k / 2u;
    var sum = vec4<f32>(0.0);
    var centre = Sample(vec4<f32>(0.0), -1.0, 0u);
    for (var b = 0u; b < k; b++) {
        for (var a = 0u; a < k; a++) {
            let s = cast_ray(f32(id.x) + (f32(a) + 0.5) / f32(k), f32(id.y) + (f32(b) + 0.5) / f32(k));
            sum += s.colour;
            if (k & 1u) == 1u && a == mid && b == mid {
                centre = s;
            }
        }
    }
    if (k & 1u) == 0u {
        centre = cast_ray(f32(id.x) + 0.5, f32(id.y) + 0.5);
    }
    out_colour[pixel] = sum / f32(k * k);
    out_depth[pixel] = centre.depth;
    out_steps[pixel] = centre.steps;
}
