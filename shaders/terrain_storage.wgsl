// The storage-buffer variant of the terrain shader, appended to `terrain.wgsl` (see there) where
// vertex shaders can read storage buffers (WebGPU, Vulkan, Metal, DX12): the patches and the
// height pool are two storage buffers, and an instance picks its `Patch` by `instance_index`.

@group(0) @binding(1) var<storage, read> patches: array<Patch>;
@group(0) @binding(2) var<storage, read> heights: array<i32>;

// Word `i` of the height pool.
fn pool_word(i: u32) -> i32 {
    return heights[i];
}

@vertex
fn vs_main(@builtin(vertex_index) vi: u32, @builtin(instance_index) ii: u32) -> VsOut {
    return terrain_vertex(vi, patches[ii]);
}
