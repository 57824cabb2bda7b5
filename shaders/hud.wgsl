// The viewer's text overlay: one instanced quad per glyph (and one for the background box),
// pulled from a per-instance vertex buffer; glyphs are 8×8 cells of a 1024×8 R8 font texture.

struct Screen {
    size: vec2<f32>,
    _pad: vec2<f32>,
}

@group(0) @binding(0) var<uniform> screen: Screen;
@group(0) @binding(1) var font: texture_2d<f32>;

struct Quad {
    @location(0) pos: vec2<f32>,
    @location(1) size: vec2<f32>,
    @location(2) glyph: u32,
    @location(3) colour: vec4<f32>,
}

struct Out {
    @builtin(position) pos: vec4<f32>,
    @location(0) cell: vec2<f32>,
    @location(1) @interpolate(flat) glyph: u32,
    @location(2) colour: vec4<f32>,
}

@vertex
fn vs_main(@builtin(vertex_index) v: u32, q: Quad) -> Out {
    // Triangle strip: (0,0), (1,0), (0,1), (1,1).
    let corner = vec2<f32>(f32(v & 1u), f32((v >> 1u) & 1u));
    let px = q.pos + corner * q.size;
    var out: Out;
    out.pos = vec4<f32>(px.x / screen.size.x * 2.0 - 1.0, 1.0 - px.y / screen.size.y * 2.0, 0.0, 1.0);
    out.cell = corner * 8.0;
    out.glyph = q.glyph;
    out.colour = q.colour;
    return out;
}

@fragment
fn fs_main(in: Out) -> @location(0) vec4<f32> {
    // Codes past ASCII are the background box: a flat translucent fill.
    if in.glyph >= 128u {
        return in.colour;
    }
    let texel = vec2<i32>(i32(in.glyph) * 8 + min(i32(in.cell.x), 7), min(i32(in.cell.y), 7));
    if textureLoad(font, texel, 0).r < 0.5 {
        discard;
    }
    return in.colour;
}
