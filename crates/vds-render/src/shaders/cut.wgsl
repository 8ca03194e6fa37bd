// The cut, drawn by vertex pulling: vertex `i` is corner `i % 3` of slot `i / 3`. Slots hold
// vertex indices (and a part id); the vertex records (`nodes`, `node_attrs`, `node_spheres`)
// hold the proxy positions of the nodes the cut uses (`VertexPool` in update.rs). A free slot
// becomes a zero-area triangle. Each vertex reads only its own corner's record (on the software rasteriser
// the vertex fetches dominate, and slots are in no spatial order): the face normal comes from
// screen-space derivatives of the position, and per-triangle colours from the provoking
// (first) vertex. Mirrors `FrameUniforms` and `GpuNode` in the Rust code.

struct Frame {
    world_to_clip: mat4x4<f32>,
    // xyz: eye position; w: focal length in pixels.
    eye: vec4<f32>,
    // xyz: unit direction towards the light; w: ambient term.
    light: vec4<f32>,
    threshold_px: f32,
    // 0: part colours, 1: node depth, 2: screen-space error.
    colouring: u32,
    // 0: faceted, 1: smooth (node normals).
    shading: u32,
    wireframe: u32,
    max_depth: f32,
    cull_outside: u32,
    _pad0: f32,
    _pad1: f32,
    // Outward frustum planes: dot(n, x) + d > 0 outside.
    planes: array<vec4<f32>, 5>,
};

@group(0) @binding(0) var<uniform> frame: Frame;
@group(0) @binding(1) var<storage, read> nodes: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> node_attrs: array<vec2<u32>>;
@group(0) @binding(3) var<storage, read> slots: array<vec4<u32>>;
@group(0) @binding(4) var<storage, read> node_spheres: array<vec4<f32>>;

// True when the sphere (centre, radius) lies entirely outside one frustum plane.
fn outside(sphere: vec4<f32>) -> bool {
    for (var i = 0u; i < 5u; i = i + 1u) {
        if (dot(frame.planes[i].xyz, sphere.xyz) + frame.planes[i].w > sphere.w) {
            return true;
        }
    }
    return false;
}

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) @interpolate(flat) colour: vec3<f32>,
    @location(1) smooth_normal: vec3<f32>,
    @location(2) world: vec3<f32>,
    @location(3) barycentric: vec3<f32>,
};

fn hash(x: u32) -> u32 {
    var h = x * 0x9E3779B1u;
    h = h ^ (h >> 15u);
    h = h * 0x85EBCA77u;
    h = h ^ (h >> 13u);
    return h;
}

fn hue(h: f32) -> vec3<f32> {
    let k = vec3<f32>(0.0, 2.0 / 3.0, 1.0 / 3.0);
    return clamp(abs(fract(vec3<f32>(h) + k) * 6.0 - 3.0) - 1.0, vec3<f32>(0.0), vec3<f32>(1.0));
}

// A blue → green → red ramp for debug colourings, `x` in [0, 1].
fn ramp(x: f32) -> vec3<f32> {
    return hue(0.66 * (1.0 - clamp(x, 0.0, 1.0)));
}

fn part_colour(part: u32) -> vec3<f32> {
    // Golden-ratio steps around the hue circle keep neighbouring part ids far apart; the
    // hash varies the lightness a little so that parts of similar hue still separate.
    let base = hue(fract(f32(part) * 0.618034 + 0.13));
    let light = 0.75 + 0.2 * f32(hash(part) & 0xFFu) / 255.0;
    // Pastel: CAD parts read better tinted than saturated.
    return mix(vec3<f32>(light), base, 0.5);
}

fn decode_normal(packed: u32) -> vec3<f32> {
    let x = f32(bitcast<i32>(packed << 16u) >> 16u) / 32767.0;
    let y = f32(bitcast<i32>(packed) >> 16u) / 32767.0;
    var n = vec3<f32>(x, y, 1.0 - abs(x) - abs(y));
    if (n.z < 0.0) {
        let xy = (1.0 - abs(n.yx)) * select(vec2<f32>(-1.0), vec2<f32>(1.0), n.xy >= vec2<f32>(0.0));
        n = vec3<f32>(xy, n.z);
    }
    let l = length(n);
    return select(vec3<f32>(0.0, 0.0, 1.0), n / l, l > 0.0);
}

fn screen_error(id: u32) -> f32 {
    let node = nodes[id];
    let distance = max(length(node.xyz - frame.eye.xyz), 1e-20);
    return frame.eye.w * node.w / distance;
}

@vertex
fn vs_main(@builtin(vertex_index) index: u32) -> VertexOut {
    var out: VertexOut;
    let slot = slots[index / 3u];
    let k = index % 3u;
    out.barycentric = vec3<f32>(f32(k == 0u), f32(k == 1u), f32(k == 2u));
    // A triangle with a corner node entirely off-screen is off-screen at full detail: do not
    // draw its coarse stand-in (see `Style::cull_outside`). All three vertices decide alike.
    let culled = frame.cull_outside != 0u && slot.x != 0xFFFFFFFFu
        && (outside(node_spheres[slot.x]) || outside(node_spheres[slot.y]) || outside(node_spheres[slot.z]));
    if (slot.x == 0xFFFFFFFFu || culled) {
        // A free slot: all three corners on one point inside the clip volume, so the
        // rasteriser drops a zero-area triangle. (A triangle outside the volume would be
        // culled too, but makes software rasterisers such as llvmpipe send the whole draw
        // through their clipping path: 2.5 M free slots cost 3.5 s a frame that way.)
        out.clip = vec4<f32>(0.0, 0.0, 0.5, 1.0);
        return out;
    }
    var corner = slot.x;
    if (k == 1u) {
        corner = slot.y;
    } else if (k == 2u) {
        corner = slot.z;
    }
    let node = nodes[corner];
    let attrs = node_attrs[corner];
    out.clip = frame.world_to_clip * vec4<f32>(node.xyz, 1.0);
    out.world = node.xyz;
    out.smooth_normal = decode_normal(attrs.y);
    // Flat outputs take the first vertex's value: for debug colourings that is corner 0.
    if (frame.colouring == 1u) {
        out.colour = ramp(f32(attrs.x) / max(frame.max_depth, 1.0));
    } else if (frame.colouring == 2u) {
        out.colour = ramp(screen_error(corner) / max(frame.threshold_px, 1e-6) * 0.5);
    } else {
        out.colour = part_colour(slot.w);
    }
    return out;
}

@fragment
fn fs_main(in: VertexOut) -> @location(0) vec4<f32> {
    var n = cross(dpdx(in.world), dpdy(in.world));
    let l = length(n);
    n = select(vec3<f32>(0.0, 0.0, 1.0), n / l, l > 0.0);
    if (frame.shading == 1u) {
        n = normalize(in.smooth_normal);
    }
    // CAD soup is not consistently oriented: light both sides.
    let to_eye = frame.eye.xyz - in.world;
    if (dot(n, to_eye) < 0.0) {
        n = -n;
    }
    let diffuse = max(dot(n, frame.light.xyz), 0.0);
    var colour = in.colour * (frame.light.w + (1.0 - frame.light.w) * diffuse);
    if (frame.wireframe != 0u) {
        let width = fwidth(in.barycentric);
        let edge = smoothstep(vec3<f32>(0.0), width * 1.2, in.barycentric);
        let on_edge = 1.0 - min(edge.x, min(edge.y, edge.z));
        colour = mix(colour, vec3<f32>(0.08, 0.08, 0.1), on_edge * 0.85);
    }
    return vec4<f32>(colour, 1.0);
}
