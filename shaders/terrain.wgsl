// Terrain of a C-BDAM cut: every drawn half-patch is one instance of the shared N×N grid.
//
// Vertex pulling: there is no per-vertex buffer. The shared index buffer holds grid vertex
// numbers `j·N + i` (so the index *is* the patch's (u, v) position); the instance picks its slot
// of the height pool and its placement. Positions are relative to the eye, in metres, computed
// from per-patch origins the CPU subtracted in f64: no large numbers reach f32.
//
// This file is not a whole module: the renderer appends one of two small variants, which say
// where the instance's `Patch` and the pool's words come from (`pool_word`) and hold the entry
// point `vs_main`: `terrain_storage.wgsl` (storage buffers: WebGPU, Vulkan, Metal, DX12) or
// `terrain_texture.wgsl` (an instance-stepped vertex buffer and an integer texture: WebGL2).
// Everything else — placement, normals, nodata, colours — is this file's, shared by both.

struct Frame {
    // World-minus-eye to clip space.
    view_proj: mat4x4<f32>,
    // Unit vector towards the sun, world frame (x east, y north, z up); w unused.
    sun: vec4<f32>,
    // z relative to the eye of height unit h is `z_base + z_scale·h` (f64 on the CPU).
    z_base: f32,
    z_scale: f32,
    // Metres of height unit h: `m_offset + m_unit·h`, for the colour ramp.
    m_offset: f32,
    m_unit: f32,
    // Colour ramp: land from `ramp_lo` to `ramp_hi` metres; below 0 m is water when the data
    // goes below sea level.
    ramp_lo: f32,
    ramp_hi: f32,
    // Grid side N.
    n: u32,
    // 0: hypsometric colours; 1: colour by level (debug).
    mode: u32,
    // Data rectangle in lattice units: drawn where 0 ≤ x ≤ data_max.x, 0 ≤ y ≤ data_max.y.
    data_max: vec2<f32>,
    // Whether the data reaches below sea level (water colours below 0 m).
    has_sea: u32,
    // 1: a colour repository is draped; each slot holds N² heights, then N² colours (RGB8
    // packed in a word, red in the low byte), and they replace the hypsometric ramp.
    draped: u32,
    // 1 on a planet: after the heights (and colours), a slot holds 6·N² words of vertex
    // positions relative to the patch origin (per vertex x, y, z rounded to f32, then what the
    // rounding left, as f32 bits); no data rectangle is clipped.
    planet: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

// One drawn half-patch (64 bytes, `PatchInstance` on the CPU).
struct Patch {
    // World x, y of grid point (0, 0) minus the eye's, metres.
    origin_rel: vec2<f32>,
    // World x, y step of grid index i and of j, metres.
    u_world: vec2<f32>,
    v_world: vec2<f32>,
    // The same map in exact lattice integers, for clipping to the data rectangle.
    origin_lat: vec2<i32>,
    u_lat: vec2<i32>,
    v_lat: vec2<i32>,
    // Slot of the height pool holding this patch's N×N heights (and colours when draped).
    slot: u32,
    level: u32,
    // 0: split diagonal i == j; 1: i + j == N − 1.
    diagonal: u32,
    // 0: positive half, 1: negative half (codec `Half` order).
    half: u32,
    // Planets: z of the patch origin minus the eye (x, y in `origin_rel`), and +1 when the
    // cross product of the grid's i and j steps faces out of the globe on this patch, −1 when in.
    origin_z: f32,
    facing: f32,
    pad_a: u32,
    pad_b: u32,
    // Planets: what rounding the origin minus the eye to f32 left.
    origin_lo_x: f32,
    origin_lo_y: f32,
    origin_lo_z: f32,
    pad: u32,
}

@group(0) @binding(0) var<uniform> frame: Frame;
// Binding 2 is the height pool (`pool_word`), binding 1 the patches where they are in storage:
// see the variants.

// First word of a patch's slot: slots are N² words, 2·N² when colours follow the heights.
fn slot_base(p: Patch) -> u32 {
    return p.slot * frame.n * frame.n * (1u + frame.draped + 6u * frame.planet);
}

fn position_word(p: Patch, v: u32, k: u32) -> f32 {
    return bitcast<f32>(pool_word(slot_base(p) + frame.n * frame.n * (1u + frame.draped) + 6u * v + k));
}

// A planet vertex's position relative to its patch origin, rounded to f32 (for normals).
fn offset_at(p: Patch, v: u32) -> vec3<f32> {
    return vec3<f32>(position_word(p, v, 0u), position_word(p, v, 1u), position_word(p, v, 2u));
}

// A planet vertex's position minus the eye: the rounded parts first (near the eye they cancel
// exactly), then what their rounding left.
fn eye_relative(p: Patch, v: u32) -> vec3<f32> {
    let big = vec3<f32>(p.origin_rel, p.origin_z) + offset_at(p, v);
    let small = vec3<f32>(p.origin_lo_x, p.origin_lo_y, p.origin_lo_z)
        + vec3<f32>(position_word(p, v, 3u), position_word(p, v, 4u), position_word(p, v, 5u));
    return big + small;
}

// Position difference along (da, db) at (a, b) on a planet: central where both neighbours are in
// the half, one-sided at the half's edges (as `slope`).
fn position_slope(p: Patch, a: i32, b: i32, da: i32, db: i32) -> vec3<f32> {
    let n = i32(frame.n);
    let fwd = in_half(p, a + da, b + db);
    let back = in_half(p, a - da, b - db);
    let here = offset_at(p, u32(b * n + a));
    if fwd && back {
        return 0.5 * (offset_at(p, u32((b + db) * n + a + da)) - offset_at(p, u32((b - db) * n + a - da)));
    } else if fwd {
        return offset_at(p, u32((b + db) * n + a + da)) - here;
    } else if back {
        return here - offset_at(p, u32((b - db) * n + a - da));
    }
    return vec3<f32>(0.0);
}

// The (unnormalised) normal of a planet patch at grid point (a, b), up to the patch's `facing`:
// the cross product of the tangents along i and j. At the ends of the split diagonal one of them
// has no neighbour in the half on either side (`position_slope` gives 0, and the cross product
// with it a zero normal, which normalises to NaN and darkens every triangle around the vertex);
// there the diagonal, which always has a neighbour in the half, stands in for it:
// e_i + e_j (diagonal 0) or e_i − e_j (diagonal 1).
fn planet_normal(p: Patch, a: i32, b: i32) -> vec3<f32> {
    var ti = position_slope(p, a, b, 1, 0);
    var tj = position_slope(p, a, b, 0, 1);
    let zero = vec3<f32>(0.0);
    if all(ti == zero) || all(tj == zero) {
        if p.diagonal == 0u {
            let td = position_slope(p, a, b, 1, 1);
            if all(ti == zero) {
                ti = td - tj;
            } else {
                tj = td - ti;
            }
        } else {
            let td = position_slope(p, a, b, 1, -1);
            if all(ti == zero) {
                ti = td + tj;
            } else {
                tj = ti - td;
            }
        }
    }
    return cross(ti, tj);
}

struct VsOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) normal: vec3<f32>,
    // Lattice position, to discard fragments outside the data rectangle.
    @location(1) lattice: vec2<f32>,
    // Height in metres, for the colour ramp.
    @location(2) metres: f32,
    @location(3) @interpolate(flat) level: u32,
    // 1 at vertices with data (or outside the data rectangle, which `lattice` clips), 0 at
    // nodata; interpolated, so it is exactly 1 only inside triangles whose corners all have data.
    @location(4) valid: f32,
    // Draped colour (0 when none is draped).
    @location(5) colour: vec3<f32>,
}

// `NODATA_BIT` of client/src/draw/mod.rs: nodata heights are stored as `h ^ NODATA_BIT`, which
// puts them outside ±MAX_ABS_HEIGHT (44 000 000 < 2^30).
const NODATA_BIT: i32 = 1073741824;
const MAX_ABS_HEIGHT: i32 = 44000000;

fn is_nodata(raw: i32) -> bool {
    return raw > MAX_ABS_HEIGHT || raw < -MAX_ABS_HEIGHT;
}

// The height of a pool entry, nodata mark removed.
fn unmark(raw: i32) -> i32 {
    if is_nodata(raw) {
        return raw ^ NODATA_BIT;
    }
    return raw;
}

// Whether grid point (a, b) belongs to the patch's own half (split diagonal included). Normals
// use only these points: the other half of a slot holds a mirror image, whose differences
// across the diagonal would flatten the slope there.
fn in_half(p: Patch, a: i32, b: i32) -> bool {
    let n = i32(frame.n);
    if a < 0 || b < 0 || a >= n || b >= n {
        return false;
    }
    // Same rule as `Layout::half_of_point` (positive: i > j, or i + j > N − 1).
    var s: i32;
    if p.diagonal == 0u {
        s = a - b;
    } else {
        s = a + b - (n - 1);
    }
    if s == 0 {
        return true;
    }
    return (s > 0) == (p.half == 0u);
}

fn height_at(p: Patch, a: i32, b: i32) -> f32 {
    let n = i32(frame.n);
    return f32(unmark(pool_word(slot_base(p) + u32(b * n + a))));
}

// Derivative of the height (units per grid step) along (da, db) at (a, b): central where both
// neighbours are in the half, one-sided at the half's edges.
fn slope(p: Patch, a: i32, b: i32, da: i32, db: i32) -> f32 {
    let fwd = in_half(p, a + da, b + db);
    let back = in_half(p, a - da, b - db);
    if fwd && back {
        return 0.5 * (height_at(p, a + da, b + db) - height_at(p, a - da, b - db));
    } else if fwd {
        return height_at(p, a + da, b + db) - height_at(p, a, b);
    } else if back {
        return height_at(p, a, b) - height_at(p, a - da, b - db);
    }
    return 0.0;
}

// Grid vertex `vi` (= j·N + i) of patch `p`: the vertex stage of both variants' `vs_main`.
fn terrain_vertex(vi: u32, p: Patch) -> VsOut {
    let i = vi % frame.n;
    let j = vi / frame.n;
    let raw = pool_word(slot_base(p) + vi);
    let h = f32(unmark(raw));
    var pos: vec3<f32>;
    var nrm: vec3<f32>;
    if frame.planet != 0u {
        pos = eye_relative(p, vi);
        nrm = p.facing * planet_normal(p, i32(i), i32(j));
    } else {
        let xy = p.origin_rel + f32(i) * p.u_world + f32(j) * p.v_world;
        pos = vec3<f32>(xy, frame.z_base + frame.z_scale * h);

        // Normal from the tangents along i and j (world metres).
        let dh_di = slope(p, i32(i), i32(j), 1, 0) * frame.z_scale;
        let dh_dj = slope(p, i32(i), i32(j), 0, 1) * frame.z_scale;
        nrm = cross(vec3<f32>(p.u_world, dh_di), vec3<f32>(p.v_world, dh_dj));
        // Odd levels' grids are mirrored (negative determinant): keep the normal pointing up.
        if nrm.z < 0.0 {
            nrm = -nrm;
        }
    }

    let lat = p.origin_lat + i32(i) * p.u_lat + i32(j) * p.v_lat;
    var out: VsOut;
    out.clip = frame.view_proj * vec4<f32>(pos, 1.0);
    out.normal = normalize(nrm);
    out.lattice = vec2<f32>(lat);
    out.metres = frame.m_offset + frame.m_unit * h;
    out.level = p.level;
    // The mask is don't care outside the data rectangle, which `outside_data` clips anyway.
    out.valid = select(1.0, 0.0, is_nodata(raw) && !outside_data(vec2<f32>(lat)));
    if frame.planet != 0u {
        out.valid = select(1.0, 0.0, is_nodata(raw));
    }
    out.colour = vec3<f32>(0.0);
    if frame.draped != 0u {
        let packed = bitcast<u32>(pool_word(slot_base(p) + frame.n * frame.n + vi));
        out.colour = unpack4x8unorm(packed).rgb;
    }
    return out;
}

// Hypsometric tints: lowland green, through tan and brown, to grey rock and snow. Every stop
// keeps green ≥ 0.45 and shading never goes below `AMBIENT`, so pure magenta (the tests'
// background) cannot come out of this shader.
fn land_colour(t: f32) -> vec3<f32> {
    let c0 = vec3<f32>(0.33, 0.56, 0.31);
    let c1 = vec3<f32>(0.56, 0.68, 0.38);
    let c2 = vec3<f32>(0.83, 0.77, 0.52);
    let c3 = vec3<f32>(0.66, 0.53, 0.42);
    let c4 = vec3<f32>(0.72, 0.70, 0.68);
    let c5 = vec3<f32>(0.97, 0.97, 0.97);
    let x = clamp(t, 0.0, 1.0);
    if x < 0.2 {
        return mix(c0, c1, x / 0.2);
    } else if x < 0.45 {
        return mix(c1, c2, (x - 0.2) / 0.25);
    } else if x < 0.7 {
        return mix(c2, c3, (x - 0.45) / 0.25);
    } else if x < 0.9 {
        return mix(c3, c4, (x - 0.7) / 0.2);
    }
    return mix(c4, c5, (x - 0.9) / 0.1);
}

fn water_colour(depth: f32) -> vec3<f32> {
    // Lighter on shelves, darker in the deep ocean (depth in metres, positive).
    let t = clamp(depth / 6000.0, 0.0, 1.0);
    return mix(vec3<f32>(0.45, 0.66, 0.85), vec3<f32>(0.10, 0.22, 0.50), sqrt(t));
}

fn level_colour(level: u32) -> vec3<f32> {
    switch level % 8u {
        case 0u: { return vec3<f32>(0.90, 0.30, 0.25); }
        case 1u: { return vec3<f32>(0.95, 0.60, 0.20); }
        case 2u: { return vec3<f32>(0.90, 0.85, 0.25); }
        case 3u: { return vec3<f32>(0.45, 0.80, 0.30); }
        case 4u: { return vec3<f32>(0.25, 0.75, 0.75); }
        case 5u: { return vec3<f32>(0.35, 0.50, 0.90); }
        case 6u: { return vec3<f32>(0.65, 0.40, 0.85); }
        default: { return vec3<f32>(0.85, 0.45, 0.65); }
    }
}

const AMBIENT: f32 = 0.35;

// Heights outside the data rectangle are unconstrained by the codec: never show them. The
// tolerance (relative to the extent, f32 interpolation being relative too) absorbs rounding of
// fragments exactly on the rectangle's edge.
fn outside_data(lattice: vec2<f32>) -> bool {
    if frame.planet != 0u {
        return false;
    }
    let eps = 1e-5 * max(1.0, max(frame.data_max.x, frame.data_max.y));
    return lattice.x < -eps || lattice.y < -eps || lattice.x > frame.data_max.x + eps
        || lattice.y > frame.data_max.y + eps;
}

// Fragments of triangles with a nodata corner: the surface there interpolates towards heights
// that are predictions, not data, so none of it is drawn (a threshold of ½ would draw half of
// each such triangle, i.e. invented surface up to half a sample into the hole). The margin only
// absorbs interpolation rounding of the constant 1.
fn touches_nodata(valid: f32) -> bool {
    return valid < 0.999;
}

// Triangle edges of the wireframe overlay (drawn with PolygonMode::Line), blended over the
// surface so that dense meshes darken it rather than turn it black.
@fragment
fn fs_wire(in: VsOut) -> @location(0) vec4<f32> {
    if outside_data(in.lattice) || touches_nodata(in.valid) {
        discard;
    }
    return vec4<f32>(0.0, 0.0, 0.0, 0.45);
}

@fragment
fn fs_main(in: VsOut) -> @location(0) vec4<f32> {
    if outside_data(in.lattice) || touches_nodata(in.valid) {
        discard;
    }
    if !(length(in.normal) > 1e-6) { return vec4<f32>(1.0, 0.0, 0.0, 1.0); }
    let nrm = normalize(in.normal);
    let lambert = max(dot(nrm, frame.sun.xyz), 0.0);
    let shade = AMBIENT + (1.0 - AMBIENT) * lambert;
    var base: vec3<f32>;
    if frame.mode == 1u {
        base = level_colour(in.level);
    } else if frame.draped != 0u {
        // Hillshade × the draped colour: the lighting is the same as the ramp's.
        base = in.colour;
    } else if frame.has_sea != 0u && in.metres < 0.0 {
        base = water_colour(-in.metres);
    } else {
        base = land_colour((in.metres - frame.ramp_lo) / max(frame.ramp_hi - frame.ramp_lo, 1e-3));
    }
    return vec4<f32>(base * shade, 1.0);
}
