// Volume ray casting (render::gpu_volume): one invocation per pixel, front to back.
//
// The ray is the reference ray caster's (render::reference_volume): cut to the exact
// interval it spends inside the box of voxel centres and the node's crop region, then
// sampled at t_k = t0 + k·dt, the last segment ending at the exit. Each segment [t_k,
// t_k+1] is classified by the pre-integrated table (render::preint) at its two end values,
// its opacity scaled to its length, its colour shaded with the gradient at its middle.
//
// `main` draws one volume through one brick per dispatch: a volume larger than one 3-D
// texture is cut into bricks, and each dispatch draws the segments whose start lies in its
// brick's owned box (the boxes partition index space), continuing the pixel's running
// colour, opacity and depth in `state`. A segment's values come from the same position
// and the same voxels in whichever brick owns it (a brick's texture holds the voxels
// around its box that its segments read), so bricked and whole volumes draw the same
// picture bit for bit.
//
// `fused` draws two overlapping volumes in one pass, each sampled on its own grid, as the
// reference fuses them: the ray is cut at every volume's entry and exit; each piece is
// stepped at the finest step of the volumes inside it; at each segment every volume inside
// is classified by its own table (and shaded by its own gradient), extinctions add and
// the colour is the extinction-weighted mean.
//
// The line `// VOLUMES` is replaced before compiling by the two volumes' bindings (1 and
// 9) and their readers `voxel0` and `voxel1` (render::gpu_volume::gpu): a 3-D texture of
// the stored type, or a storage buffer of the stored values packed into words.

// One volume as the rays see it.
struct Vol {
    // Eye, view direction, right and up in this volume's voxel-index space (rays' t stays
    // the world distance: the map is affine).
    eye: vec4<f32>,
    fwd: vec4<f32>,
    right: vec4<f32>,
    up: vec4<f32>,
    // Box of the drawn samples (voxel centres; padded half a voxel on a single-slice axis).
    box_lo: vec4<f32>,
    box_hi: vec4<f32>,
    // Voxel counts; w: voxels per block edge of the min-max grid.
    dims: vec4<u32>,
    // Blocks per axis; w: flags (SHADE, GRADIENT_OPACITY, SKIP, POINT_LIGHTS).
    blocks: vec4<u32>,
    // dt (world), -, level per value, level at value 0
    march: vec4<f32>,
    // rescale slope, intercept, table levels, lowest level with opacity less one
    values: vec4<f32>,
    // ambient, diffuse, specular, specular power
    shading: vec4<f32>,
    // gradient opacity: segment length in unit distances, its points; crop half-spaces
    gradient: vec4<f32>,
    // Index-space gradient (stored units per voxel) to world gradient (real units per
    // world unit): rows.
    g_x: vec4<f32>,
    g_y: vec4<f32>,
    g_z: vec4<f32>,
    // Crop region: inside where dot(n, p) + w ≥ 0 (index space).
    crop: array<vec4<f32>, 16>,
}

struct Params {
    // World-space camera: eye (w: 1 for a parallel camera), view direction (w: half the
    // view width, world units for parallel, at distance 1 for perspective), right (w: half
    // the height), up.
    eye: vec4<f32>,
    fwd: vec4<f32>,
    right: vec4<f32>,
    up: vec4<f32>,
    // The brick `main` draws: its segments start inside [owned_lo, owned_hi) (±1e30 on
    // the volume's outer faces); it holds voxels from `origin` on, `extent` of them.
    owned_lo: vec4<f32>,
    owned_hi: vec4<f32>,
    origin: vec4<i32>,
    extent: vec4<u32>,
    // width, height, lights, flags (COMPOSITE, FIRST)
    counts: vec4<u32>,
    // termination, -, -, -
    control: vec4<f32>,
    // Lights: xyz direction toward the light (w 1), position (w 2), or the headlight (w 0).
    light: array<vec4<f32>, 8>,
    light_color: array<vec4<f32>, 8>,
    vol: array<Vol, 2>,
}

@group(0) @binding(0) var<uniform> P: Params;
// VOLUMES
@group(0) @binding(2) var table0: texture_2d<f32>;
// One bit per block: every segment starting in it is transparent.
@group(0) @binding(3) var<storage, read> clear0: array<u32>;
// Per block: the largest value its segments' samples read (MIP's skipping).
@group(0) @binding(4) var<storage, read> block_max: array<f32>;
// Gradient opacity: (gradient magnitude, factor) points.
@group(0) @binding(5) var<storage, read> gradient_points0: array<vec2<f32>>;
// Per pixel: premultiplied colour and opacity (MIP: highest value, its t, -, found).
@group(0) @binding(6) var<storage, read_write> state: array<vec4<f32>>;
// Per pixel: where the opacity passed 0.5 (world distance), -1 where it has not.
@group(0) @binding(7) var<storage, read_write> depth: array<f32>;
// Per pixel: segments classified.
@group(0) @binding(8) var<storage, read_write> samples: array<u32>;
// The second volume (`fused`; `main` is given the first's again): its voxels at binding 9.
@group(0) @binding(10) var table1: texture_2d<f32>;
@group(0) @binding(11) var<storage, read> clear1: array<u32>;
@group(0) @binding(12) var<storage, read> gradient_points1: array<vec2<f32>>;

// Params.counts.w
const COMPOSITE: u32 = 1u;
const FIRST: u32 = 2u;
// Vol.blocks.w
const SHADE: u32 = 1u;
const GRADIENT_OPACITY: u32 = 2u;
const SKIP: u32 = 4u;
const POINT_LIGHTS: u32 = 8u;

fn voxel(v: u32, i: vec3<i32>) -> f32 {
    if v == 0u {
        return voxel0(i - P.origin.xyz);
    }
    return voxel1(i);
}

// The trilinear field of volume v in stored units at index-space point p (clamped to the
// volume), as geometry::trilinear.
fn field(v: u32, p: vec3<f32>) -> f32 {
    let top = vec3<i32>(P.vol[v].dims.xyz) - 1;
    let q = clamp(p, vec3<f32>(0.0), vec3<f32>(top));
    let f0 = floor(q);
    let i0 = vec3<i32>(f0);
    let i1 = min(i0 + 1, top);
    let t = q - f0;
    let c00 = lerp(voxel(v, vec3(i0.x, i0.y, i0.z)), voxel(v, vec3(i1.x, i0.y, i0.z)), t.x);
    let c10 = lerp(voxel(v, vec3(i0.x, i1.y, i0.z)), voxel(v, vec3(i1.x, i1.y, i0.z)), t.x);
    let c01 = lerp(voxel(v, vec3(i0.x, i0.y, i1.z)), voxel(v, vec3(i1.x, i0.y, i1.z)), t.x);
    let c11 = lerp(voxel(v, vec3(i0.x, i1.y, i1.z)), voxel(v, vec3(i1.x, i1.y, i1.z)), t.x);
    return lerp(lerp(c00, c10, t.y), lerp(c01, c11, t.y), t.z);
}

// a + (b − a)·t: exactly a where b = a. (WGSL's mix, a·(1 − t) + b·t, rounds a constant
// field to values a few ulps apart, whose differences then give a flat region a random
// normal: rings of speckle in shading where the eye sits in a uniform region.)
fn lerp(a: f32, b: f32, t: f32) -> f32 {
    return a + (b - a) * t;
}

fn real(v: u32, stored: f32) -> f32 {
    return stored * P.vol[v].values.x + P.vol[v].values.y;
}

// Central differences one voxel either side, shortened at the volume's edge (the rule of
// render::volume_shading::gradient), in stored units per voxel: the six trilinear samples
// field(p ± a step along each axis), each computed as `field` computes it, from the 32
// voxels they read between them (six separate samples would load 48). Along each axis the
// four voxels from the centre cell's lower one less one are loaded, and each sample picks
// its two from them.
fn gradient_at(v: u32, p: vec3<f32>) -> vec3<f32> {
    let dims = vec3<i32>(P.vol[v].dims.xyz);
    let top = dims - 1;
    let topf = vec3<f32>(top);
    // The centre cell, as `field` takes it.
    let q = clamp(p, vec3<f32>(0.0), topf);
    let f0 = floor(q);
    let c0 = vec3<i32>(f0);
    let c1 = min(c0 + 1, top);
    let t = q - f0;
    // Rows along x (y, z of the cell's corners), four voxels each from c0.x − 1.
    let r00 = window_x(v, c0.x, vec2<i32>(c0.y, c0.z), top.x);
    let r10 = window_x(v, c0.x, vec2<i32>(c1.y, c0.z), top.x);
    let r01 = window_x(v, c0.x, vec2<i32>(c0.y, c1.z), top.x);
    let r11 = window_x(v, c0.x, vec2<i32>(c1.y, c1.z), top.x);
    // Along y: x-interpolated values at four y from c0.y − 1, for the cell's two z.
    let y0 = vec4<f32>(
        lerp(voxel(v, vec3<i32>(c0.x, max(c0.y - 1, 0), c0.z)), voxel(v, vec3<i32>(c1.x, max(c0.y - 1, 0), c0.z)), t.x),
        lerp(r00.y, r00.z, t.x),
        lerp(r10.y, r10.z, t.x),
        lerp(voxel(v, vec3<i32>(c0.x, min(c0.y + 2, top.y), c0.z)), voxel(v, vec3<i32>(c1.x, min(c0.y + 2, top.y), c0.z)), t.x),
    );
    let y1 = vec4<f32>(
        lerp(voxel(v, vec3<i32>(c0.x, max(c0.y - 1, 0), c1.z)), voxel(v, vec3<i32>(c1.x, max(c0.y - 1, 0), c1.z)), t.x),
        lerp(r01.y, r01.z, t.x),
        lerp(r11.y, r11.z, t.x),
        lerp(voxel(v, vec3<i32>(c0.x, min(c0.y + 2, top.y), c1.z)), voxel(v, vec3<i32>(c1.x, min(c0.y + 2, top.y), c1.z)), t.x),
    );
    // Along z: xy-interpolated values at four z from c0.z − 1.
    let zb = max(c0.z - 1, 0);
    let za = min(c0.z + 2, top.z);
    let z = vec4<f32>(
        lerp(
            lerp(voxel(v, vec3<i32>(c0.x, c0.y, zb)), voxel(v, vec3<i32>(c1.x, c0.y, zb)), t.x),
            lerp(voxel(v, vec3<i32>(c0.x, c1.y, zb)), voxel(v, vec3<i32>(c1.x, c1.y, zb)), t.x),
            t.y,
        ),
        y0.y + (y0.z - y0.y) * t.y,
        y1.y + (y1.z - y1.y) * t.y,
        lerp(
            lerp(voxel(v, vec3<i32>(c0.x, c0.y, za)), voxel(v, vec3<i32>(c1.x, c0.y, za)), t.x),
            lerp(voxel(v, vec3<i32>(c0.x, c1.y, za)), voxel(v, vec3<i32>(c1.x, c1.y, za)), t.x),
            t.y,
        ),
    );
    // The two positions along each axis, and the sample at each.
    let x = q;
    let up = min(topf - x, vec3<f32>(1.0));
    let down = min(x, vec3<f32>(1.0));
    let span = up + down;
    var g = vec3<f32>(0.0);
    if span.x > 0.0 {
        let hi = along(x.x + up.x, topf.x, c0.x);
        let lo = along(x.x - down.x, topf.x, c0.x);
        let at_hi = lerp(lerp(pick2(r00, hi), pick2(r10, hi), t.y), lerp(pick2(r01, hi), pick2(r11, hi), t.y), t.z);
        let at_lo = lerp(lerp(pick2(r00, lo), pick2(r10, lo), t.y), lerp(pick2(r01, lo), pick2(r11, lo), t.y), t.z);
        g.x = (at_hi - at_lo) / span.x;
    }
    if span.y > 0.0 {
        let hi = along(x.y + up.y, topf.y, c0.y);
        let lo = along(x.y - down.y, topf.y, c0.y);
        g.y = (lerp(pick2(y0, hi), pick2(y1, hi), t.z) - lerp(pick2(y0, lo), pick2(y1, lo), t.z)) / span.y;
    }
    if span.z > 0.0 {
        g.z = (pick2(z, along(x.z + up.z, topf.z, c0.z)) - pick2(z, along(x.z - down.z, topf.z, c0.z))) / span.z;
    }
    return g;
}

// The voxels x = c − 1 … c + 2 (clamped into the volume) of the row (y, z) of volume v.
fn window_x(v: u32, c: i32, yz: vec2<i32>, top: i32) -> vec4<f32> {
    return vec4<f32>(
        voxel(v, vec3<i32>(max(c - 1, 0), yz.x, yz.y)),
        voxel(v, vec3<i32>(c, yz.x, yz.y)),
        voxel(v, vec3<i32>(min(c + 1, top), yz.x, yz.y)),
        voxel(v, vec3<i32>(min(c + 2, top), yz.x, yz.y)),
    );
}

// Where a sample at coordinate s falls along one axis, as `field` takes it: its two voxels
// as places in the window of four from c − 1 (x, y), and its fraction (z). A place beyond
// the window comes only with a fraction of 0 (s + 1 rounded up to a whole number): its
// weight is nil.
fn along(s: f32, top: f32, c: i32) -> vec3<f32> {
    let sc = clamp(s, 0.0, top);
    let f = floor(sc);
    let i0 = i32(f);
    let i1 = min(i0 + 1, i32(top));
    return vec3<f32>(f32(clamp(i0 - c + 1, 0, 3)), f32(clamp(i1 - c + 1, 0, 3)), sc - f);
}

// The window's value at place k (0 … 3).
fn pick(w: vec4<f32>, k: f32) -> f32 {
    return select(select(w.x, w.y, k == 1.0), select(w.z, w.w, k == 3.0), k >= 2.0);
}

// The sample `a` (from `along`) on the window w.
fn pick2(w: vec4<f32>, a: vec3<f32>) -> f32 {
    return lerp(pick(w, a.x), pick(w, a.y), a.z);
}

fn to_world(v: u32, g: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(P.vol[v].g_x.xyz, g), dot(P.vol[v].g_y.xyz, g), dot(P.vol[v].g_z.xyz, g));
}

fn table_entry(v: u32, f: i32, b: i32) -> vec4<f32> {
    if v == 0u {
        return textureLoad(table0, vec2<i32>(b, f), 0);
    }
    return textureLoad(table1, vec2<i32>(b, f), 0);
}

// The table's bilinear lookup at fractional levels (PreintTable::lookup).
fn lookup(v: u32, front: f32, back: f32) -> vec4<f32> {
    let n = i32(P.vol[v].values.z);
    let f0 = min(i32(front), n - 2);
    let b0 = min(i32(back), n - 2);
    let tf = front - f32(f0);
    let tb = back - f32(b0);
    let a = mix(table_entry(v, f0, b0), table_entry(v, f0, b0 + 1), tb);
    let b = mix(table_entry(v, f0 + 1, b0), table_entry(v, f0 + 1, b0 + 1), tb);
    return mix(a, b, tf);
}

fn level(v: u32, value: f32) -> f32 {
    let m = P.vol[v].march;
    return clamp(value * m.z + m.w, 0.0, P.vol[v].values.z - 1.0);
}

// A table entry for a segment `length` times the table's: opacity 1 − (1 − α)^length,
// colour scaled with it (composite::for_length).
fn for_length(e: vec4<f32>, length: f32) -> vec4<f32> {
    if length == 1.0 || e.a <= 0.0 {
        return e;
    }
    var a = 1.0;
    if e.a < 1.0 {
        a = 1.0 - pow(1.0 - e.a, length);
    }
    return vec4<f32>(e.rgb * (a / e.a), a);
}

fn normalize_or_zero(x: vec3<f32>) -> vec3<f32> {
    let l = length(x);
    if l > 0.0 {
        return x / l;
    }
    return vec3<f32>(0.0);
}

fn gradient_point(v: u32, i: u32) -> vec2<f32> {
    if v == 0u {
        return gradient_points0[i];
    }
    return gradient_points1[i];
}

// The piecewise-linear gradient opacity factor at magnitude g, clamped to its end values.
fn gradient_factor(v: u32, g: f32) -> f32 {
    let n = u32(P.vol[v].gradient.y);
    let first = gradient_point(v, 0u);
    if g <= first.x {
        return first.y;
    }
    for (var i = 1u; i < n; i++) {
        let b = gradient_point(v, i);
        if g < b.x {
            let a = gradient_point(v, i - 1u);
            return a.y + (b.y - a.y) * (g - a.x) / (b.x - a.x);
        }
    }
    return gradient_point(v, n - 1u).y;
}

// Shading (render::volume_shading): colour · (ambient + Σ diffuse · max(N'·L, 0) · light) +
// Σ specular · (N'·H)^power · light, two-sided; flat regions lit as facing the light.
fn shade(v: u32, c: vec4<f32>, g: vec3<f32>, at: vec3<f32>, dir: vec3<f32>) -> vec4<f32> {
    let k = P.vol[v].shading;
    let len = length(g);
    let has_normal = len > 0.0;
    let to_eye = -dir;
    var n = vec3<f32>(0.0);
    if has_normal {
        n = g / len;
        if dot(n, to_eye) < 0.0 {
            n = -n;
        }
    }
    var d = vec3<f32>(k.x);
    var s = vec3<f32>(0.0);
    for (var i = 0u; i < P.counts.z; i++) {
        let light = P.light[i];
        var to_light = to_eye;
        if light.w == 1.0 {
            to_light = light.xyz;
        } else if light.w == 2.0 {
            to_light = normalize_or_zero(light.xyz - at);
        }
        var lambert = 1.0;
        var highlight = 0.0;
        if has_normal {
            let h = normalize_or_zero(to_light + to_eye);
            let nl = dot(n, to_light);
            let nh = dot(n, h);
            lambert = max(nl, 0.0);
            if nl > 0.0 && nh > 0.001 && k.z > 0.0 {
                highlight = pow(nh, k.w);
            }
        }
        d += k.y * lambert * P.light_color[i].rgb;
        s += k.z * highlight * P.light_color[i].rgb;
    }
    return vec4<f32>(c.rgb * d + s * c.a, c.a);
}

// Whether the table may give the segment between `front` and `back` some opacity.
fn visible(v: u32, front: f32, back: f32) -> bool {
    return max(level(v, real(v, front)), level(v, real(v, back))) >= P.vol[v].values.w;
}

// The segment [t, t + len] of volume v's ray (o, d) between values `front` and `back`
// (stored units): pre-integrated, its gradient opacity applied and shaded, as
// shear_warp::shading::FrameShading::shade does (the opacity per unit distance scaled by
// the gradient opacity's factor). Zero where the table makes it transparent.
fn classify(v: u32, o: vec3<f32>, d: vec3<f32>, t: f32, len: f32, front: f32, back: f32, origin_world: vec3<f32>, dir_world: vec3<f32>) -> vec4<f32> {
    let lf = level(v, real(v, front));
    let lb = level(v, real(v, back));
    if max(lf, lb) < P.vol[v].values.w {
        return vec4<f32>(0.0);
    }
    let dt = P.vol[v].march.x;
    var c = for_length(lookup(v, lf, lb), len / dt);
    let flags = P.vol[v].blocks.w;
    if c.a > 0.0 && (flags & (SHADE | GRADIENT_OPACITY)) != 0u {
        let tm = t + 0.5 * len;
        let g = to_world(v, gradient_at(v, o + d * tm));
        if (flags & GRADIENT_OPACITY) != 0u {
            let factor = gradient_factor(v, length(g));
            if factor < 1.0 {
                let units = P.vol[v].gradient.x * len / dt;
                let per_unit = 1.0 - pow(max(1.0 - c.a, 0.0), 1.0 / units);
                let scaled = 1.0 - pow(1.0 - factor * per_unit, units);
                c = vec4<f32>(c.rgb * (scaled / c.a), scaled);
            }
        }
        if (flags & SHADE) != 0u && c.a > 0.0 {
            var at = vec3<f32>(0.0);
            if (flags & POINT_LIGHTS) != 0u {
                at = origin_world + dir_world * tm;
            }
            c = shade(v, c, g, at, dir_world);
        }
    }
    return c;
}

// The ray's parameter interval inside volume v's box and crop region (geometry::clip_box,
// then crop::clip_interval); empty where t0 ≥ t1.
fn interval(v: u32, o: vec3<f32>, d: vec3<f32>) -> vec2<f32> {
    var t0 = 0.0;
    var t1 = 3.0e38;
    let lo = P.vol[v].box_lo;
    let hi = P.vol[v].box_hi;
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
    for (var i = 0u; i < u32(P.vol[v].gradient.z); i++) {
        let h = P.vol[v].crop[i];
        let a = dot(h.xyz, o) + h.w;
        let b = dot(h.xyz, d);
        if b == 0.0 {
            if a < 0.0 {
                return vec2<f32>(1.0, 0.0);
            }
        } else if b > 0.0 {
            t0 = max(t0, -a / b);
        } else {
            t1 = min(t1, -a / b);
        }
    }
    return vec2<f32>(t0, t1);
}

// The interval of the ray inside the box [lo, hi) (no t ≥ 0 bound).
fn slab(o: vec3<f32>, d: vec3<f32>, lo: vec3<f32>, hi: vec3<f32>) -> vec2<f32> {
    var t0 = -3.0e38;
    var t1 = 3.0e38;
    for (var k = 0; k < 3; k++) {
        if d[k] == 0.0 {
            if o[k] < lo[k] || o[k] >= hi[k] {
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

fn owned(p: vec3<f32>) -> bool {
    return all(p >= P.owned_lo.xyz) && all(p < P.owned_hi.xyz);
}

// The block of volume v's min-max grid holding index-space point p, as a flat index.
fn block_of(v: u32, p: vec3<f32>) -> u32 {
    let g = P.vol[v].blocks.xyz;
    let b = min(vec3<u32>(max(p, vec3<f32>(0.0)) / f32(P.vol[v].dims.w)), g - 1u);
    return b.x + g.x * (b.y + g.y * b.z);
}

fn block_clear(v: u32, p: vec3<f32>) -> bool {
    let b = block_of(v, p);
    if v == 0u {
        return (clear0[b >> 5u] & (1u << (b & 31u))) != 0u;
    }
    return (clear1[b >> 5u] & (1u << (b & 31u))) != 0u;
}

// Where the ray leaves the block of volume v holding p.
fn block_exit(v: u32, o: vec3<f32>, d: vec3<f32>, p: vec3<f32>) -> f32 {
    let e = f32(P.vol[v].dims.w);
    let lo = floor(max(p, vec3<f32>(0.0)) / e) * e;
    let hi = lo + e;
    var t = 3.0e38;
    for (var k = 0; k < 3; k++) {
        if d[k] > 0.0 {
            t = min(t, (hi[k] - o[k]) / d[k]);
        } else if d[k] < 0.0 {
            t = min(t, (lo[k] - o[k]) / d[k]);
        }
    }
    return t;
}

// The first step at or after where the ray leaves a clear block (`exit`), on the grid
// t0 + k·dt: at least the step after k, at most one past `k_max` (the march's end).
fn leap(k: u32, exit: f32, t0: f32, dt: f32, k_max: u32) -> u32 {
    return max(k + 1u, u32(min(ceil((exit - t0) / dt), f32(k_max) + 1.0)));
}

// Where segment k of a march from t0 to t1 in steps of dt ends: the next step, or t1 for
// the last (k_last).
fn segment_end(k: u32, k_last: u32, t0: f32, t1: f32, dt: f32) -> f32 {
    if k < k_last {
        return t0 + f32(k + 1u) * dt;
    }
    return t1;
}

// A pixel's ray: in world space, and through a parallel view's image plane or from the
// eye, as camera::RayGenerator::ray.
struct Ray {
    sx: f32,
    sy: f32,
    inv: f32,
    origin_world: vec3<f32>,
    dir_world: vec3<f32>,
}

fn pixel_ray(id: vec2<u32>) -> Ray {
    var r: Ray;
    r.sx = (2.0 * (f32(id.x) + 0.5) / f32(P.counts.x) - 1.0) * P.fwd.w;
    r.sy = (1.0 - 2.0 * (f32(id.y) + 0.5) / f32(P.counts.y)) * P.right.w;
    r.origin_world = P.eye.xyz;
    r.dir_world = P.fwd.xyz;
    r.inv = 1.0;
    if P.eye.w == 1.0 {
        r.origin_world += P.right.xyz * r.sx + P.up.xyz * r.sy;
    } else {
        r.inv = 1.0 / sqrt(1.0 + r.sx * r.sx + r.sy * r.sy);
        r.dir_world = (P.fwd.xyz + P.right.xyz * r.sx + P.up.xyz * r.sy) * r.inv;
    }
    return r;
}

// The ray in volume v's index space: origin and direction.
fn index_origin(v: u32, r: Ray) -> vec3<f32> {
    if P.eye.w == 1.0 {
        return P.vol[v].eye.xyz + P.vol[v].right.xyz * r.sx + P.vol[v].up.xyz * r.sy;
    }
    return P.vol[v].eye.xyz;
}

fn index_dir(v: u32, r: Ray) -> vec3<f32> {
    if P.eye.w == 1.0 {
        return P.vol[v].fwd.xyz;
    }
    return (P.vol[v].fwd.xyz + P.vol[v].right.xyz * r.sx + P.vol[v].up.xyz * r.sy) * r.inv;
}

// Composites a segment (premultiplied c) at [t, t + len] into acc, recording in z where
// the opacity passed 0.5 (uniform extinction within the segment).
fn accumulate(acc: ptr<function, vec4<f32>>, z: ptr<function, f32>, c: vec4<f32>, t: f32, len: f32) {
    let before = (*acc).a;
    *acc += (1.0 - before) * c;
    if before < 0.5 && (*acc).a >= 0.5 {
        var f = 0.0;
        if c.a < 1.0 {
            f = clamp(log(0.5 / (1.0 - before)) / log(1.0 - c.a), 0.0, 1.0);
        }
        *z = t + f * len;
    }
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    let width = P.counts.x;
    if id.x >= width || id.y >= P.counts.y {
        return;
    }
    let pixel = id.x + width * id.y;
    let composite = (P.counts.w & COMPOSITE) != 0u;

    var acc = vec4<f32>(0.0);
    var z = -1.0;
    var n = 0u;
    if !composite {
        acc = vec4<f32>(-3.0e38, 0.0, 0.0, 0.0);
    }
    if (P.counts.w & FIRST) == 0u {
        acc = state[pixel];
        z = depth[pixel];
        n = samples[pixel];
    }

    let r = pixel_ray(id.xy);
    let o = index_origin(0u, r);
    let d = index_dir(0u, r);
    let span = interval(0u, o, d);
    let own = slab(o, d, P.owned_lo.xyz, P.owned_hi.xyz);
    let done = composite && acc.a >= P.control.x;
    if span.x < span.y && own.x <= own.y && !done {
        let t0 = span.x;
        let t1 = span.y;
        let dt = P.vol[0].march.x;
        // Segments that may start in this brick: a step either side of its part of the ray.
        let k_last = u32(max(ceil((t1 - t0) / dt), 1.0)) - 1u;
        let k_lo = u32(max(floor((own.x - t0) / dt) - 1.0, 0.0));
        let k_hi = min(u32(clamp(ceil((own.y - t0) / dt) + 1.0, 0.0, f32(k_last))), k_last);
        let skip = (P.vol[0].blocks.w & SKIP) != 0u;
        var k = k_lo;
        // The value at t_k when the previous segment's end left it (exactly the same
        // computation as sampling it again).
        var carried = false;
        var front = 0.0;
        if !composite {
            loop {
                if k > k_hi {
                    break;
                }
                let t = t0 + f32(k) * dt;
                let p = o + d * t;
                if !owned(p) {
                    k++;
                    continue;
                }
                if skip && block_max[block_of(0u, p)] <= acc.x {
                    k = leap(k, block_exit(0u, o, d, p), t0, dt, k_hi);
                    continue;
                }
                let tb = segment_end(k, k_last, t0, t1, dt);
                let len = max(tb - t, 0.0);
                n++;
                let tm = t + 0.5 * len;
                let v = real(0u, field(0u, o + d * tm));
                if v > acc.x {
                    acc = vec4<f32>(v, tm, 0.0, 1.0);
                }
                k++;
            }
        }
        // Composite: an outer loop whose each pass first walks (cheaply: block test, one
        // value, the table's transparency test) to the next segment the table does not make
        // transparent, then classifies and shades that one. On a SIMD target that runs every
        // branch under a mask (lavapipe), the shading's cost is paid once per pass instead of
        // once per step.
        loop {
            if !composite || k > k_hi {
                break;
            }
            var found = false;
            var t = 0.0;
            var len = 0.0;
            var back = 0.0;
            loop {
                if k > k_hi {
                    break;
                }
                t = t0 + f32(k) * dt;
                let p = o + d * t;
                if !owned(p) {
                    k++;
                    carried = false;
                    continue;
                }
                if skip && block_clear(0u, p) {
                    k = leap(k, block_exit(0u, o, d, p), t0, dt, k_hi);
                    carried = false;
                    continue;
                }
                let tb = segment_end(k, k_last, t0, t1, dt);
                // One value per pass of this loop (each is eight texel loads, paid by every
                // SIMD lane whether it needs it or not): the segment's start where the
                // previous segment did not leave it, then its end.
                let value = field(0u, select(p, o + d * tb, carried));
                if !carried {
                    front = value;
                    carried = true;
                    continue;
                }
                back = value;
                len = max(tb - t, 0.0);
                n++;
                if visible(0u, front, back) {
                    found = true;
                    break;
                }
                front = back;
                k++;
            }
            if !found {
                break;
            }
            let c = classify(0u, o, d, t, len, front, back, r.origin_world, r.dir_world);
            front = back;
            k++;
            if c.a > 0.0 {
                accumulate(&acc, &z, c, t, len);
                if acc.a >= P.control.x {
                    break;
                }
            }
        }
    }
    state[pixel] = acc;
    depth[pixel] = z;
    samples[pixel] = n;
}

// Two volumes' segments over the same stretch of ray fused (shear_warp::fusion::fuse):
// α = 1 − (1 − α₁)(1 − α₂), colour α·(σ₁ĉ₁ + σ₂ĉ₂)/(σ₁ + σ₂), σᵢ = −ln(1 − αᵢ), ĉᵢ = cᵢ/αᵢ.
fn fuse(a: vec4<f32>, b: vec4<f32>) -> vec4<f32> {
    if b.a <= 0.0 {
        return a;
    }
    if a.a <= 0.0 {
        return b;
    }
    let most = 1.0 - 1e-6;
    let s1 = -log(1.0 - min(a.a, most));
    let s2 = -log(1.0 - min(b.a, most));
    let alpha = 1.0 - (1.0 - a.a) * (1.0 - b.a);
    let w1 = alpha * s1 / ((s1 + s2) * a.a);
    let w2 = alpha * s2 / ((s1 + s2) * b.a);
    return vec4<f32>(a.rgb * w1 + b.rgb * w2, alpha);
}

@compute @workgroup_size(8, 8, 1)
fn fused(@builtin(global_invocation_id) id: vec3<u32>) {
    let width = P.counts.x;
    if id.x >= width || id.y >= P.counts.y {
        return;
    }
    let pixel = id.x + width * id.y;
    let r = pixel_ray(id.xy);
    var o = array<vec3<f32>, 2>(index_origin(0u, r), index_origin(1u, r));
    var d = array<vec3<f32>, 2>(index_dir(0u, r), index_dir(1u, r));
    var spans = array<vec2<f32>, 2>(interval(0u, o[0], d[0]), interval(1u, o[1], d[1]));
    // The cuts: every entry and exit, sorted.
    var cuts = array<f32, 4>(3.0e38, 3.0e38, 3.0e38, 3.0e38);
    var m = 0u;
    for (var v = 0u; v < 2u; v++) {
        if spans[v].x < spans[v].y {
            cuts[m] = spans[v].x;
            cuts[m + 1u] = spans[v].y;
            m += 2u;
        }
    }
    for (var i = 1u; i < m; i++) {
        var j = i;
        while j > 0u && cuts[j - 1u] > cuts[j] {
            let x = cuts[j];
            cuts[j] = cuts[j - 1u];
            cuts[j - 1u] = x;
            j--;
        }
    }
    var acc = vec4<f32>(0.0);
    var z = -1.0;
    var n = 0u;
    var stop = false;
    for (var piece = 0u; piece + 1u < m && !stop; piece++) {
        let c0 = cuts[piece];
        let c1 = cuts[piece + 1u];
        if !(c0 < c1) {
            continue;
        }
        // The volumes inside for the whole piece, and its step: the finest of theirs.
        let mid = 0.5 * (c0 + c1);
        var inside = array<bool, 2>(false, false);
        var dt = 3.0e38;
        for (var v = 0u; v < 2u; v++) {
            inside[v] = spans[v].x <= mid && mid < spans[v].y;
            if inside[v] {
                dt = min(dt, P.vol[v].march.x);
            }
        }
        if dt >= 3.0e38 {
            continue;
        }
        let k_last = u32(max(ceil((c1 - c0) / dt), 1.0)) - 1u;
        var front = array<f32, 2>(0.0, 0.0);
        var carried = false;
        var k = 0u;
        loop {
            if k > k_last {
                break;
            }
            let t = c0 + f32(k) * dt;
            // Leap where every volume inside is transparent here, to the nearest block exit.
            var clear = true;
            var exit = 3.0e38;
            for (var v = 0u; v < 2u; v++) {
                if inside[v] {
                    let p = o[v] + d[v] * t;
                    if (P.vol[v].blocks.w & SKIP) == 0u || !block_clear(v, p) {
                        clear = false;
                    } else {
                        exit = min(exit, block_exit(v, o[v], d[v], p));
                    }
                }
            }
            if clear {
                k = leap(k, exit, c0, dt, k_last);
                carried = false;
                continue;
            }
            let tb = segment_end(k, k_last, c0, c1, dt);
            let len = max(tb - t, 0.0);
            n++;
            var c = vec4<f32>(0.0);
            for (var v = 0u; v < 2u; v++) {
                if inside[v] {
                    if !carried {
                        front[v] = field(v, o[v] + d[v] * t);
                    }
                    let back = field(v, o[v] + d[v] * tb);
                    c = fuse(c, classify(v, o[v], d[v], t, len, front[v], back, r.origin_world, r.dir_world));
                    front[v] = back;
                }
            }
            carried = true;
            if c.a > 0.0 {
                accumulate(&acc, &z, c, t, len);
                if acc.a >= P.control.x {
                    stop = true;
                    break;
                }
            }
            k++;
        }
    }
    state[pixel] = acc;
    depth[pixel] = z;
    samples[pixel] = n;
}
