// The points renderer. Spheres: every particle a sphere, drawn as a screen-space triangle
// round its projection (an ellipse, found exactly), and each fragment intersected exactly
// with the sphere along the pixel's ray (the same rays as every other renderer: pixel
// centres, row 0 at the top); writes the colour shaded by a headlight, the distance along
// the ray (Z) and a depth for the depth test (the distance, mapped linearly between the near
// and far planes). Positions are relative to the eye, so f32 keeps its precision far from
// the origin. Splats: a compute pass over screen tiles (cs_splat, below).

struct View {
    forward: vec4<f32>,
    right: vec4<f32>,
    up: vec4<f32>,
    half_w: f32,
    half_h: f32,
    width: f32,
    height: f32,
    parallel: u32,
    near: f32,
    far: f32,
    // Splats: each splat's opacity at its centre, and the tiles across the image.
    opacity: f32,
    tiles_x: u32,
    // Splats: 1 for the first pass over the particles (the sums start empty), 0 for a pass
    // that carries on the sums the one before left.
    first_batch: u32,
};

@group(0) @binding(0) var<uniform> view: View;
// Eye-relative centre and radius of each sphere.
@group(0) @binding(1) var<storage, read> spheres: array<vec4<f32>>;
// Each sphere's colour (linear RGB, from the colour map).
@group(0) @binding(2) var<storage, read> colours: array<vec4<f32>>;

// The sphere and its colour travel with each vertex (flat): a fragment reads no buffer.
struct VOut {
    @builtin(position) pos: vec4<f32>,
    // Eye-relative centre and radius (world axes), for the spheres' ray intersection.
    @location(0) @interpolate(flat) sphere: vec4<f32>,
    @location(1) @interpolate(flat) colour: vec4<f32>,
};

// The triangle round a unit circle (its incircle): three vertices twice the radius out.
const TRIANGLE = array<vec2<f32>, 3>(vec2<f32>(0.0, 2.0), vec2<f32>(-1.7320508, -1.0), vec2<f32>(1.7320508, -1.0));

@vertex
fn vs(@builtin(vertex_index) vi: u32, @builtin(instance_index) ii: u32) -> VOut {
    let s = spheres[ii];
    let r = s.w;
    let cam = vec3<f32>(dot(s.xyz, view.right.xyz), dot(s.xyz, view.up.xyz), dot(s.xyz, view.forward.xyz));
    var out: VOut;
    out.sphere = s;
    out.colour = colours[ii];
    // A sphere reaching the eye plane is not drawn (a degenerate triangle): its projection
    // is unbounded. The near plane lies just in front of every other sphere.
    if (cam.z - r <= 0.0 && view.parallel == 0u) {
        out.pos = vec4<f32>(-2.0, -2.0, 0.5, 1.0);
        return out;
    }
    // The sphere's projection on the image plane (x / z, y / z; parallel: x, y), exactly:
    // an ellipse with centre p0, semi-axis a along u (toward the centre's foot, radially)
    // and b across it. In perspective, from the cone of rays tangent to the sphere,
    // (p·c)² = (|c|² − r²)|p|² for p = (x, y, 1): with e = c_z² − r², the centre is
    // c_xy·c_z / e, a = r·√(|c|² − r²) / e and b = r / √e. Parallel: the circle of radius r.
    // One triangle round it, the ellipse its incircle's image (1.65 times the ellipse's
    // area): a software rasteriser pays per triangle as much as per fragment, and two
    // triangles of a quad round the bounds cost more than the third more fragments.
    var p0 = cam.xy;
    var u = vec2<f32>(1.0, 0.0);
    var a = r;
    var b = r;
    if (view.parallel == 0u) {
        let e = (cam.z - r) * (cam.z + r);
        let rho = length(cam.xy);
        if (rho > 0.0) {
            u = cam.xy / rho;
        }
        p0 = cam.xy * (cam.z / e);
        a = r * sqrt(max((cam.z - r) * (cam.z + r) + rho * rho, 0.0)) / e;
        b = r / sqrt(e);
    }
    // A fiftieth of a pixel of margin (in image-plane units along the finer axis), so a
    // pixel centre just inside is never lost to rounding (f32 puts the bound within about
    // 1e-4 pixel). Not more: at a few pixels across, a pixel each side would quadruple
    // the fragments of a sphere.
    let m = 0.04 * max(view.half_w / view.width, view.half_h / view.height);
    let t = TRIANGLE[vi];
    let xy = (p0 + (a + m) * t.x * u + (b + m) * t.y * vec2<f32>(-u.y, u.x)) / vec2<f32>(view.half_w, view.half_h);
    // The triangle's depth: the sphere's nearest distance from the eye (every fragment's
    // ray meets the sphere no nearer), so the fragment depth is never nearer than it.
    var nearest = length(cam) - r;
    if (view.parallel != 0u) {
        nearest = cam.z - r;
    }
    let z = clamp((nearest - view.near) / (view.far - view.near), 0.0, 1.0);
    out.pos = vec4<f32>(xy, z, 1.0);
    return out;
}

struct FOut {
    @location(0) colour: vec4<f32>,
    @location(1) dist: f32,
    @builtin(frag_depth) depth: f32,
};

// The image-plane point (sx, sy) of a fragment's pixel centre (row 0 at the top).
fn image_point(px: vec2<f32>) -> vec2<f32> {
    return vec2<f32>((2.0 * px.x / view.width - 1.0) * view.half_w, (1.0 - 2.0 * px.y / view.height) * view.half_h);
}

// The ray through a fragment's pixel centre: origin and unit direction, eye-relative.
struct Ray {
    o: vec3<f32>,
    d: vec3<f32>,
};

fn pixel_ray(px: vec2<f32>) -> Ray {
    let s = image_point(px);
    var o = vec3<f32>(0.0, 0.0, 0.0);
    var d = view.forward.xyz;
    if (view.parallel != 0u) {
        o = view.right.xyz * s.x + view.up.xyz * s.y;
    } else {
        d = normalize(view.forward.xyz + view.right.xyz * s.x + view.up.xyz * s.y);
    }
    return Ray(o, d);
}

@fragment
fn fs(in: VOut) -> FOut {
    let s = in.sphere;
    let ray = pixel_ray(in.pos.xy);
    let o = ray.o;
    let d = ray.d;
    // The ray's nearest approach to the centre, then back along the ray to the surface
    // (no difference of two large squares).
    let oc = o - s.xyz;
    let b = dot(oc, d);
    let q = oc - b * d;
    let disc = s.w * s.w - dot(q, q);
    if (disc < 0.0) {
        discard;
    }
    let t = -b - sqrt(disc);
    if (t <= 0.0) {
        discard;
    }
    let n = normalize(o + t * d - s.xyz);
    var out: FOut;
    out.colour = vec4<f32>(in.colour.rgb * (0.3 + 0.7 * max(dot(n, -d), 0.0)), 1.0);
    out.dist = t;
    out.depth = clamp((t - view.near) / (view.far - view.near), 0.0, 1.0);
    return out;
}

// Gaussian splats: each particle a Gaussian blob of σ = radius / 3 about its centre, cut at
// the radius, weighted by the ray's nearest approach q to the centre: α = opacity ·
// exp(−q² / 2σ²). Order-independent (weighted blended): per pixel, Σ colour · α, Π (1 − α),
// Σ α, and the least distance to the point of nearest approach among the splats the ray
// passes within σ of.
//
// Drawn by a compute pass, not by the rasteriser: one workgroup per tile of TILE_W × TILE_H
// pixels (constants the host puts before this source: it bins the splats by the same tiles),
// each invocation a 2 × 2 block of pixels, looping over the splats binned to its tile (by the
// host, in particle order, from each splat's exact ellipse). The sums are the blending's,
// in the same order; on lavapipe the 1M-particle plume at 1920×1080 draws in about 0.5 s
// this way where the triangles' fragments, blended into three float targets, took 1.1 s.

// Each tile's splats, one after another (tile t's from tile_start[t] to tile_start[t + 1],
// row-major tiles), two vec4 each: the centre in the camera's frame (x right, y up,
// z forward; a pixel's ray is (sx, sy, 1) normalised in perspective, or starts at
// (sx, sy, 0) along z in parallel) and the falloff −4.5 log2(e) / radius²; then the colour
// and 1 / c_z. Made so by the host (in f64) that a pixel's test needs no division: two
// divisions in the loop cost a tenth of the draw on lavapipe (see the README).
@group(0) @binding(3) var<storage, read> splat_data: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read> tile_start: array<u32>;
// Per pixel (row-major, row 0 at the top): (Σ colour · α, Π (1 − α)), then (Σ α, distance).
@group(0) @binding(6) var<storage, read_write> splat_sums: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read_write> splat_weight_dist: array<vec2<f32>>;
// The tile each workgroup draws: the tiles shuffled, because lavapipe hands each of its
// threads one contiguous run of workgroups, and a run of neighbouring tiles holds more or
// fewer splats than another (a thread sat idle a third of the time with tiles in order).
@group(0) @binding(8) var<storage, read> tile_order: array<u32>;

// What a pixel's splats leave: Σ colour · α, Π (1 − α), Σ α and the least distance.
struct SplatAcc {
    colour: vec3<f32>,
    clear: f32,
    weight: f32,
    dist: f32,
};

// A pixel's image-plane point s, 1 / (1 + |s|²) and 1 / √(1 + |s|²).
struct SplatPixel {
    s: vec2<f32>,
    inv_dd: f32,
    inv_len: f32,
};

fn splat_pixel(x: u32, y: u32) -> SplatPixel {
    let s = image_point(vec2<f32>(f32(x) + 0.5, f32(y) + 0.5));
    let dd = 1.0 + dot(s, s);
    return SplatPixel(s, 1.0 / dd, inverseSqrt(dd));
}

// log2(e) · 4.5: the cut at 3σ on the falloff's scale (q²/r² = 1 there); and at σ.
const SPLAT_CUT: f32 = 6.4921277;
const SPLAT_SIGMA: f32 = 0.72134752;

// Adds one splat (centre c in the camera's frame and its falloff; where the ray through
// the centre meets the image plane; colour) to a pixel's sums.
fn splat_add(acc: ptr<function, SplatAcc>, px: SplatPixel, c: vec4<f32>, foot: vec2<f32>, colour: vec3<f32>) {
    // The pixel's offset from where the ray through the centre meets the image plane; no
    // difference of two large squares. Perspective: with D = (sx, sy, 1),
    // q = |c × D| / |D|, and c × D = (−c_z Δy, c_z Δx, c_x Δy − c_y Δx) for
    // Δ = s − c_xy / c_z; the distance along the ray to the point of nearest approach is
    // c · D / |D|. Parallel: q = |Δ|, distance c_z.
    let dl = px.s - foot;
    var q2 = dot(dl, dl);
    var along = c.z;
    if (view.parallel == 0u) {
        let k = c.x * dl.y - c.y * dl.x;
        q2 = (c.z * c.z * q2 + k * k) * px.inv_dd;
        along = (dot(c.xy, px.s) + c.z) * px.inv_len;
    }
    // e = −4.5 log2(e) q²/r²: the Gaussian's exponent in base 2.
    let e = q2 * c.w;
    // Outside the cut (or behind the eye) a splat adds nothing: α = 0.
    let inside = e > -SPLAT_CUT && along > 0.0;
    let a = select(0.0, view.opacity * exp2(e), inside);
    (*acc).colour += colour * a;
    (*acc).clear *= 1.0 - a;
    (*acc).weight += a;
    (*acc).dist = select((*acc).dist, min((*acc).dist, along), inside && e >= -SPLAT_SIGMA);
}

// A pixel's sums so far: empty in the first pass, else what the pass before left.
fn splat_load(x: u32, y: u32) -> SplatAcc {
    if (view.first_batch != 0u || x >= u32(view.width) || y >= u32(view.height)) {
        return SplatAcc(vec3<f32>(0.0, 0.0, 0.0), 1.0, 0.0, 3.0e38);
    }
    let p = y * u32(view.width) + x;
    let s = splat_sums[p];
    let wd = splat_weight_dist[p];
    return SplatAcc(s.rgb, s.a, wd.x, wd.y);
}

fn splat_store(acc: SplatAcc, x: u32, y: u32) {
    if (x < u32(view.width) && y < u32(view.height)) {
        let p = y * u32(view.width) + x;
        splat_sums[p] = vec4<f32>(acc.colour, acc.clear);
        splat_weight_dist[p] = vec2<f32>(acc.weight, acc.dist);
    }
}

// Each invocation a 2 × 2 block of the tile's pixels (a tile's 8 invocations one step of
// lavapipe's 8 SIMD lanes): every splat read (the same for all the lanes; a software GPU
// reads it lane by lane) serves four pixels.
@compute @workgroup_size(TILE_W / 2u, TILE_H / 2u)
fn cs_splat(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wg: vec3<u32>) {
    let tile = tile_order[wg.y * view.tiles_x + wg.x];
    let x = TILE_W * (tile % view.tiles_x) + 2u * lid.x;
    let y = TILE_H * (tile / view.tiles_x) + 2u * lid.y;
    let p00 = splat_pixel(x, y);
    let p10 = splat_pixel(x + 1u, y);
    let p01 = splat_pixel(x, y + 1u);
    let p11 = splat_pixel(x + 1u, y + 1u);
    var a00 = splat_load(x, y);
    var a10 = splat_load(x + 1u, y);
    var a01 = splat_load(x, y + 1u);
    var a11 = splat_load(x + 1u, y + 1u);
    let end = tile_start[tile + 1u];
    for (var k = tile_start[tile]; k < end; k++) {
        let c = splat_data[2u * k];
        let colour_inv_z = splat_data[2u * k + 1u];
        let colour = colour_inv_z.rgb;
        var foot = c.xy;
        if (view.parallel == 0u) {
            foot = c.xy * colour_inv_z.w;
        }
        splat_add(&a00, p00, c, foot, colour);
        splat_add(&a10, p10, c, foot, colour);
        splat_add(&a01, p01, c, foot, colour);
        splat_add(&a11, p11, c, foot, colour);
    }
    splat_store(a00, x, y);
    splat_store(a10, x + 1u, y);
    splat_store(a01, x, y + 1u);
    splat_store(a11, x + 1u, y + 1u);
}
