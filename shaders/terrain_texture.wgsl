// The texture variant of the terrain shader, appended to `terrain.wgsl` (see there) where vertex
// shaders cannot read storage buffers (WebGL2): the patches come as an instance-stepped vertex
// buffer of the same 96-byte `PatchInstance`s, and the height pool is an `R32Sint` texture of
// `POOL_WIDTH` texels a row, word `i` at texel (i mod POOL_WIDTH, i div POOL_WIDTH), read with
// `textureLoad` (exact integers: no sampler, no filtering). The renderer's `POOL_TEXTURE_WIDTH`
// is the same number.

const POOL_WIDTH: u32 = 2048u;

@group(0) @binding(2) var heights: texture_2d<i32>;

// Word `i` of the height pool.
fn pool_word(i: u32) -> i32 {
    return textureLoad(heights, vec2<u32>(i % POOL_WIDTH, i / POOL_WIDTH), 0).x;
}

// `PatchInstance` as vertex attributes (byte offsets in the instance: 0, 16, 24, 40, 48, 64,
// 80; the padding at 72 and 92 is not read).
struct PatchAttributes {
    @location(0) origin_rel_u_world: vec4<f32>,
    @location(1) v_world: vec2<f32>,
    @location(2) origin_u_lat: vec4<i32>,
    @location(3) v_lat: vec2<i32>,
    @location(4) slot_level_diagonal_half: vec4<u32>,
    @location(5) origin_z_facing: vec2<f32>,
    @location(6) origin_lo: vec3<f32>,
}

@vertex
fn vs_main(@builtin(vertex_index) vi: u32, a: PatchAttributes) -> VsOut {
    let s = a.slot_level_diagonal_half;
    let p = Patch(
        a.origin_rel_u_world.xy, a.origin_rel_u_world.zw, a.v_world,
        a.origin_u_lat.xy, a.origin_u_lat.zw, a.v_lat,
        s.x, s.y, s.z, s.w,
        a.origin_z_facing.x, a.origin_z_facing.y, 0u, 0u,
        a.origin_lo.x, a.origin_lo.y, a.origin_lo.z, 0u,
    );
    return terrain_vertex(vi, p);
}
