// The terrain's max-quadtree, built on the GPU.
//
// Level 0 would be the lid map — one texel per bilinear patch holding the highest of its
// four corner heights, so it bounds the patch itself and not just the samples (the
// paper's section 4.3). It is not stored: the ray-caster takes it from the patch's four
// heights, which it reads anyway to intersect the patch, and the pyramid starts at level 1
// (a quarter of the patches' texels: on a software adapter, where textures live in host
// memory, a stored lid map cost as much memory as the heights themselves).
// `build_level1`: level 1 texel = max of the lids of its 2×2 patches; a patch touching a
// NoData sample, and the padding up to a power of two, count as HOLE: lower than any ray,
// so rays pass through.
// `reduce`: level L+1 texel = max of the 2×2 texels below it.

const HOLE: f32 = -3.0e38;
// Heights below this are NoData (uploaded as HOLE; NaN is not portable in shaders).
const NODATA_BELOW: f32 = -1.0e37;

struct LidParams {
    // Patches east-west, south-north.
    cells: vec2<u32>,
    pad: vec2<u32>,
}

@group(0) @binding(0) var src: texture_2d<f32>;
@group(0) @binding(1) var dst: texture_storage_2d<r32float, write>;
@group(0) @binding(2) var<uniform> lid_params: LidParams;

// The lid of patch c (HOLE where it lies past the last patch or touches NoData).
fn patch_lid(c: vec2<i32>) -> f32 {
    if c.x >= i32(lid_params.cells.x) || c.y >= i32(lid_params.cells.y) {
        return HOLE;
    }
    let z00 = textureLoad(src, c, 0).r;
    let z10 = textureLoad(src, c + vec2<i32>(1, 0), 0).r;
    let z01 = textureLoad(src, c + vec2<i32>(0, 1), 0).r;
    let z11 = textureLoad(src, c + vec2<i32>(1, 1), 0).r;
    if min(min(z00, z10), min(z01, z11)) > NODATA_BELOW {
        return max(max(z00, z10), max(z01, z11));
    }
    return HOLE;
}

@compute @workgroup_size(8, 8)
fn build_level1(@builtin(global_invocation_id) id: vec3<u32>) {
    let size = textureDimensions(dst);
    if id.x >= size.x || id.y >= size.y {
        return;
    }
    let c = vec2<i32>(id.xy) * 2;
    let v = max(max(patch_lid(c), patch_lid(c + vec2<i32>(1, 0))), max(patch_lid(c + vec2<i32>(0, 1)), patch_lid(c + vec2<i32>(1, 1))));
    textureStore(dst, vec2<i32>(id.xy), vec4<f32>(v, 0.0, 0.0, 0.0));
}

@compute @workgroup_size(8, 8)
fn reduce(@builtin(global_invocation_id) id: vec3<u32>) {
    let size = textureDimensions(dst);
    if id.x >= size.x || id.y >= size.y {
        return;
    }
    // Levels are powers of two on each side; a side already down to 1 texel stays 1.
    let last = vec2<i32>(textureDimensions(src)) - 1;
    let p = vec2<i32>(id.xy) * 2;
    let a = textureLoad(src, min(p, last), 0).r;
    let b = textureLoad(src, min(p + vec2<i32>(1, 0), last), 0).r;
    let c = textureLoad(src, min(p + vec2<i32>(0, 1), last), 0).r;
    let d = textureLoad(src, min(p + vec2<i32>(1, 1), last), 0).r;
    textureStore(dst, vec2<i32>(id.xy), vec4<f32>(max(max(a, b), max(c, d)), 0.0, 0.0, 0.0));
}
