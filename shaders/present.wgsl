// Copies the renderer's offscreen colour target onto a window's surface texture, pixel for
// pixel (the two have the same size). One full-screen triangle, no vertex buffer.

@group(0) @binding(0) var frame: texture_2d<f32>;

@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    // (0,0), (2,0), (0,2) scaled to (-1,-1), (3,-1), (-1,3): covers the whole viewport.
    let uv = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u));
    return vec4<f32>(uv * 2.0 - 1.0, 0.0, 1.0);
}

@fragment
fn fs_main(@builtin(position) p: vec4<f32>) -> @location(0) vec4<f32> {
    return textureLoad(frame, vec2<i32>(p.xy), 0);
}

// For sRGB surfaces: the offscreen image holds the bytes a PNG would get, so decode them here
// and let the surface encode them back; the window then shows the same bytes as the file.
@fragment
fn fs_srgb(@builtin(position) p: vec4<f32>) -> @location(0) vec4<f32> {
    let c = textureLoad(frame, vec2<i32>(p.xy), 0);
    let lo = c.rgb / 12.92;
    let hi = pow((c.rgb + 0.055) / 1.055, vec3<f32>(2.4));
    return vec4<f32>(select(hi, lo, c.rgb <= vec3<f32>(0.04045)), c.a);
}
