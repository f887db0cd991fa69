// The points renderer: every particle a sphere, drawn as a screen-space quad that covers
// its projection, and each fragment intersected exactly with the sphere along the pixel's
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

struct VOut {
    @builtin(position) pos: vec4<f32>,
    @location(0) @interpolate(flat) id: u32,
};

// Normalised device coordinates of a point in camera coordinates (right, up, forward).
fn ndc(c: vec3<f32>) -> vec2<f32> {
    if (view.parallel != 0u) {
        return vec2<f32>(c.x / view.half_w, c.y / view.half_h);
    }
    return vec2<f32>(c.x / (c.z * view.half_w), c.y / (c.z * view.half_h));
}

@vertex
fn vs(@builtin(vertex_index) vi: u32, @builtin(instance_index) ii: u32) -> VOut {
    let s = spheres[ii];
    let r = s.w;
    let cam = vec3<f32>(dot(s.xyz, view.right.xyz), dot(s.xyz, view.up.xyz), dot(s.xyz, view.forward.xyz));
    var out: VOut;
    out.id = ii;
    // A sphere reaching the eye plane is not drawn (a degenerate quad): its projection is
    // unbounded. The near plane lies just in front of every other sphere.
    if (cam.z - r <= 0.0 && view.parallel == 0u) {
        out.pos = vec4<f32>(-2.0, -2.0, 0.5, 1.0);
        return out;
    }
    // The sphere's projection, bounded exactly along each image axis by the tangent lines
    // from the eye in that axis's plane (lo = tan(θ − δ), hi = tan(θ + δ), sin δ = r over
    // the centre's distance in the plane): a quad about a
    // third of the size of one round the sphere's bounding cube, and fragments are what a
    // software rasteriser pays for. Parallel: centre ± r.
    var lo: vec2<f32>;
    var hi: vec2<f32>;
    if (view.parallel != 0u) {
        lo = (cam.xy - vec2<f32>(r)) / vec2<f32>(view.half_w, view.half_h);
        hi = (cam.xy + vec2<f32>(r)) / vec2<f32>(view.half_w, view.half_h);
    } else {
        // Per axis, the tangents in that axis's plane through the eye (x with the depth,
        // y with the depth): the sphere's shadow there is a circle about (c_x, c_z) or
        // (c_y, c_z), so t is the tangent length in that plane, not in 3-D.
        let t = sqrt(max(cam.xy * cam.xy + vec2<f32>(cam.z * cam.z - r * r), vec2<f32>(0.0)));
        let den_lo = cam.z * t + r * cam.xy;
        let den_hi = cam.z * t - r * cam.xy;
        if (all(den_lo > vec2<f32>(0.0)) && all(den_hi > vec2<f32>(0.0))) {
            lo = (cam.xy * t - r * cam.z) / den_lo / vec2<f32>(view.half_w, view.half_h);
            hi = (cam.xy * t + r * cam.z) / den_hi / vec2<f32>(view.half_w, view.half_h);
        } else {
            // More than 90° across (beside the eye): the bounding cube's projection.
            lo = vec2<f32>(1e30, 1e30);
            hi = vec2<f32>(-1e30, -1e30);
            for (var k = 0u; k < 8u; k = k + 1u) {
                let o = vec3<f32>(select(-r, r, (k & 1u) != 0u), select(-r, r, (k & 2u) != 0u), select(-r, r, (k & 4u) != 0u));
                let q = ndc(cam + o);
                lo = min(lo, q);
                hi = max(hi, q);
            }
        }
    }
    var corners = array<vec2<f32>, 6>(
        vec2<f32>(0.0, 0.0), vec2<f32>(1.0, 0.0), vec2<f32>(0.0, 1.0),
        vec2<f32>(0.0, 1.0), vec2<f32>(1.0, 0.0), vec2<f32>(1.0, 1.0));
    // A fiftieth of a pixel of margin, so a pixel centre just inside is never lost to
    // rounding (f32 puts the bound within about 1e-4 pixel). Not more: at a few pixels
    // across, a whole pixel each side would quadruple the fragments of a sphere.
    let m = vec2<f32>(0.04 / view.width, 0.04 / view.height);
    let xy = mix(lo - m, hi + m, corners[vi]);
    // The quad's depth: the sphere's nearest distance from the eye (every fragment's ray
    // meets the sphere no nearer), so the fragment depth is never nearer than the quad's.
    var nearest = length(cam) - r;
    if (view.parallel != 0u) {
        nearest = cam.z - r;
    }
    let z = clamp((nearest - view.near) / (view.far - view.near), 0.0, 1.0);
    out.pos = vec4<f32>(clamp(xy, vec2<f32>(-4.0), vec2<f32>(4.0)), z, 1.0);
    return out;
}

struct FOut {
    @location(0) colour: vec4<f32>,
    @location(1) dist: f32,
    @builtin(frag_depth) depth: f32,
};

// The ray through a fragment's pixel centre: origin and unit direction, eye-relative.
struct Ray {
    o: vec3<f32>,
    d: vec3<f32>,
};

fn pixel_ray(px: vec2<f32>) -> Ray {
    let sx = (2.0 * px.x / view.width - 1.0) * view.half_w;
    let sy = (1.0 - 2.0 * px.y / view.height) * view.half_h;
    var o = vec3<f32>(0.0, 0.0, 0.0);
    var d = view.forward.xyz;
    if (view.parallel != 0u) {
        o = view.right.xyz * sx + view.up.xyz * sy;
    } else {
        d = normalize(view.forward.xyz + view.right.xyz * sx + view.up.xyz * sy);
    }
    return Ray(o, d);
}

@fragment
fn fs(in: VOut) -> FOut {
    let s = spheres[in.id];
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
    out.colour = vec4<f32>(colours[in.id].rgb * (0.3 + 0.7 * max(dot(n, -d), 0.0)), 1.0);
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
    let s = spheres[in.id];
    let ray = pixel_ray(in.pos.xy);
    let oc = ray.o - s.xyz;
    let b = dot(oc, ray.d);
    let q = oc - b * ray.d;
    let q2 = dot(q, q) / (s.w * s.w);
    if (q2 >= 1.0 || -b <= 0.0) {
        discard;
    }
    let a = view.opacity * exp(-4.5 * q2);
    var out: SplatOut;
    out.colour = vec4<f32>(colours[in.id].rgb * a, a);
    out.weight = a;
    out.dist = select(3.0e38, -b, q2 <= 1.0 / 9.0);
    return out;
}
