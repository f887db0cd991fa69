// The terrain's max-quadtree, built on the GPU.
//
// Level 0 would be the lid map — one texel per bilinear patch holding the highest of its
// four corner heights, so it bounds the patch itself and not just the samples (the
// paper's section 4.3). It is not stored: the ray-caster takes it from the patch's four
// heights, which it reads anyway to intersect the patch, and the pyramid starts at level 1
// (a quarter of the patches' texels: on a software adapter, where textures live in host
// memory, a stored lid map cost as much memory as the heights themselves).
//
// The levels are stored as half floats rounded up, two to a 32-bit texel (neighbours
// along `packing.x`'s axis: 1 east, 0 north), which halves the pyramid again (a third of
// the heights' bytes → a sixth). A lid only has to bound the heights below it: rounding it
// up to the next half float (at most 1/1024 of its distance from the middle of the
// elevation range, where heights are measured from) costs a few more steps, never a
// missed hit. `unpack_lid` is the ray-caster's read.
//
// `build_level1`: level 1 texel = max of the lids of its 2×2 patches; a patch touching a
// NoData sample, and the padding up to a power of two, count as HOLE: lower than any ray,
// so rays pass through.
// `reduce`: level L+1 texel = max of the 2×2 texels below it.

const HOLE: f32 = -3.0e38;
// Heights below this are NoData (uploaded as HOLE; NaN is not portable in shaders).
const NODATA_BELOW: f32 = -1.0e37;

struct Packing {
    // Patches east-west, south-north (build_level1); the source level's texels (reduce).
    src: vec2<u32>,
    // The written level's texels (logical, before packing).
    dst: vec2<u32>,
    // x: 1 when texel pairs are neighbours east-west, 0 north-south.
    axis: vec4<u32>,
}

@group(0) @binding(0) var heights: texture_2d<f32>;
@group(0) @binding(1) var dst: texture_storage_2d<r32uint, write>;
@group(0) @binding(2) var<uniform> packing: Packing;
@group(0) @binding(3) var src: texture_2d<u32>;

// The smallest half float ≥ v, as its 16 bits (−∞ for HOLE, +∞ above the half floats).
fn half_up(v: f32) -> u32 {
    if v <= NODATA_BELOW {
        return 0xfc00u;
    }
    if v > 65504.0 {
        return 0x7c00u;
    }
    if v < -65504.0 {
        return 0xfbffu;
    }
    // Subnormal halves may be flushed to zero on the way back: keep clear of them.
    if abs(v) < 6.103515625e-5 {
        return select(0u, 0x0400u, v > 0.0);
    }
    var h = pack2x16float(vec2<f32>(v, 0.0)) & 0xffffu;
    if unpack2x16float(h).x < v {
        // One step toward +∞: up in magnitude when positive, down when negative.
        h = select(h + 1u, h - 1u, (h & 0x8000u) != 0u);
    }
    return h;
}

// The value of logical texel n of a packed level (texel pairs along packing.axis).
fn unpack_lid(n: vec2<u32>) -> f32 {
    let east = packing.axis.x == 1u;
    let word = textureLoad(src, select(vec2<u32>(n.x, n.y >> 1u), vec2<u32>(n.x >> 1u, n.y), east), 0).r;
    let pair = unpack2x16float(word);
    return select(pair.x, pair.y, (select(n.y, n.x, east) & 1u) == 1u);
}

// The two logical texels packed texel p holds.
fn pair_of(p: vec2<u32>) -> array<vec2<u32>, 2> {
    if packing.axis.x == 1u {
        return array<vec2<u32>, 2>(vec2<u32>(2u * p.x, p.y), vec2<u32>(2u * p.x + 1u, p.y));
    }
    return array<vec2<u32>, 2>(vec2<u32>(p.x, 2u * p.y), vec2<u32>(p.x, 2u * p.y + 1u));
}

// The lid of patch c (HOLE where it lies past the last patch or touches NoData).
fn patch_lid(c: vec2<u32>) -> f32 {
    if c.x >= packing.src.x || c.y >= packing.src.y {
        return HOLE;
    }
    let l = vec2<i32>(c);
    let z00 = textureLoad(heights, l, 0).r;
    let z10 = textureLoad(heights, l + vec2<i32>(1, 0), 0).r;
    let z01 = textureLoad(heights, l + vec2<i32>(0, 1), 0).r;
    let z11 = textureLoad(heights, l + vec2<i32>(1, 1), 0).r;
    if min(min(z00, z10), min(z01, z11)) > NODATA_BELOW {
        return max(max(z00, z10), max(z01, z11));
    }
    return HOLE;
}

fn level1_texel(n: vec2<u32>) -> f32 {
    if n.x >= packing.dst.x || n.y >= packing.dst.y {
        return HOLE;
    }
    let c = n * 2u;
    return max(max(patch_lid(c), patch_lid(c + vec2<u32>(1u, 0u))), max(patch_lid(c + vec2<u32>(0u, 1u)), patch_lid(c + vec2<u32>(1u, 1u))));
}

fn reduced_texel(n: vec2<u32>) -> f32 {
    if n.x >= packing.dst.x || n.y >= packing.dst.y {
        return HOLE;
    }
    // Levels are powers of two on each side; a side already down to 1 texel stays 1.
    let last = packing.src - 1u;
    let p = n * 2u;
    let a = unpack_lid(min(p, last));
    let b = unpack_lid(min(p + vec2<u32>(1u, 0u), last));
    let c = unpack_lid(min(p + vec2<u32>(0u, 1u), last));
    let d = unpack_lid(min(p + vec2<u32>(1u, 1u), last));
    return max(max(a, b), max(c, d));
}

@compute @workgroup_size(8, 8)
fn build_level1(@builtin(global_invocation_id) id: vec3<u32>) {
    let size = textureDimensions(dst);
    if id.x >= size.x || id.y >= size.y {
        return;
    }
    let n = pair_of(id.xy);
    let word = half_up(level1_texel(n[0])) | (half_up(level1_texel(n[1])) << 16u);
    textureStore(dst, vec2<i32>(id.xy), vec4<u32>(word, 0u, 0u, 0u));
}

@compute @workgroup_size(8, 8)
fn reduce(@builtin(global_invocation_id) id: vec3<u32>) {
    let size = textureDimensions(dst);
    if id.x >= size.x || id.y >= size.y {
        return;
    }
    let n = pair_of(id.xy);
    // The maximum of halves rounded up is itself a half rounded up: no second rounding.
    let word = half_up(reduced_texel(n[0])) | (half_up(reduced_texel(n[1])) << 16u);
    textureStore(dst, vec2<i32>(id.xy), vec4<u32>(word, 0u, 0u, 0u));
}
