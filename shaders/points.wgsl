// The points renderer: every particle a sphere, drawn as a screen-space triangle round
// its projection (an ellipse, found exactly), and each fragment intersected exactly with the sphere along the pixel's
// ray (the same rays as every other renderer: pixel centres, row 0 at the top). Writes the
// colour shaded by a headlight, the distance along the ray (Z) and a depth for the depth
// test (the distance, mapped linearly between the near and far planes). Positions are
// relative to the eye, so f32 keeps its precision far from the origin.

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
    // Splats: each splat's opacity at its centre.
    opacity: f32,
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
    // For the splats: the centre in the camera's frame (x right, y up, z forward), where a
    // pixel's ray is (sx, sy, 1) normalised (perspective) or starts at (sx, sy, 0) along z
    // (parallel), and where the ray through the centre meets the image plane (sx, sy).
    @location(2) @interpolate(flat) cam: vec3<f32>,
    @location(3) @interpolate(flat) foot: vec2<f32>,
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
    out.cam = cam;
    out.colour = colours[ii];
    out.foot = cam.xy;
    if (view.parallel == 0u) {
        out.foot = cam.xy / cam.z;
    }
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
// exp(−q² / 2σ²). Order-independent (weighted blended): target 0 sums colour · α (RGB)
// and multiplies (1 − α) (A), target 1 sums α, target 2 keeps the least distance to the
// point of nearest approach among splats the ray passes within σ of.
struct SplatOut {
    @location(0) colour: vec4<f32>,
    @location(1) weight: f32,
    @location(2) dist: f32,
};

@fragment
fn fs_splat(in: VOut) -> SplatOut {
    let c = vec4<f32>(in.cam, in.sphere.w);
    let s = image_point(in.pos.xy);
    // The pixel's offset from the centre's foot on the image plane; no difference of two
    // large squares. Perspective: with D = (sx, sy, 1), q = |c × D| / |D|, and
    // c × D = (−c_z Δy, c_z Δx, c_x Δy − c_y Δx) for Δ = s − c_xy / c_z; the distance along
    // the ray to the point of nearest approach is c · D / |D|. Parallel: q = |Δ|, distance c_z.
    let dl = s - in.foot;
    var q2 = dot(dl, dl);
    var along = c.z;
    if (view.parallel == 0u) {
        let k = c.x * dl.y - c.y * dl.x;
        let dd = 1.0 + dot(s, s);
        q2 = (c.z * c.z * q2 + k * k) / dd;
        along = (dot(c.xy, s) + c.z) * inverseSqrt(dd);
    }
    q2 = q2 / (c.w * c.w);
    // Outside the cut (or behind the eye) a fragment adds nothing: α = 0 leaves every sum
    // as it was, without a discard.
    let a = select(0.0, view.opacity * exp(-4.5 * q2), q2 < 1.0 && along > 0.0);
    var out: SplatOut;
    out.colour = vec4<f32>(in.colour.rgb * a, a);
    out.weight = a;
    out.dist = select(3.0e38, along, q2 <= 1.0 / 9.0 && along > 0.0);
    return out;
}
