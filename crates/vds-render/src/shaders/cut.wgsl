// The cut, drawn by vertex pulling: vertex `i` is corner `i % 3` of slot `i / 3`. Slots hold
// vertex indices (and a part id); the vertex records (`nodes`, `node_attrs`, `node_spheres`)
// hold the proxy positions of the nodes the cut uses (`VertexPool` in update.rs). A free slot
// becomes a zero-area triangle. Each vertex reads only its own corner's record (on the software rasteriser
// the vertex fetches dominate, and slots are in no spatial order): the face normal comes from
// screen-space derivatives of the position, and per-triangle colours from the provoking
// (first) vertex. Mirrors `FrameUniforms`, `GpuNode` and `PartLook::packed` in the Rust code.
//
// Per-part looks (`parts`, indexed by the slot's part id): the file's colour, hidden, picked.
// A hidden part's triangles collapse like free slots at every level of detail, since every
// triangle of every level carries the part id of the original triangles it stands for.
// Section planes discard fragments on their positive side; where a section opens a solid, its
// inside (back faces) shows in a flat colour so that the cut reads as solid.

struct Frame {
    world_to_clip: mat4x4<f32>,
    // xyz: eye position; w: focal length in pixels.
    eye: vec4<f32>,
    // xyz: unit direction towards the light; w: ambient term.
    light: vec4<f32>,
    threshold_px: f32,
    // 0: part palette, 1: node depth, 2: screen-space error, 3: the file's colours.
    colouring: u32,
    // 0: faceted, 1: smooth (node normals).
    shading: u32,
    wireframe: u32,
    max_depth: f32,
    cull_outside: u32,
    // Entries of `parts`; ids at or past it take the default look.
    part_count: u32,
    // Section planes in use (the first `section_count` of `sections`).
    section_count: u32,
    // Outward frustum planes: dot(n, x) + d > 0 outside.
    planes: array<vec4<f32>, 5>,
    // Section planes: dot(n, x) + d > 0 is cut away.
    sections: array<vec4<f32>, 3>,
};

@group(0) @binding(0) var<uniform> frame: Frame;
@group(0) @binding(1) var<storage, read> nodes: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> node_attrs: array<vec2<u32>>;
@group(0) @binding(3) var<storage, read> slots: array<vec4<u32>>;
@group(0) @binding(4) var<storage, read> node_spheres: array<vec4<f32>>;
// Per part: x = linear RGBA8 colour (alpha 0: the file gives none), y = flags.
@group(0) @binding(5) var<storage, read> parts: array<vec2<u32>>;
// A rank-tracked cut (`RankMirror` in ranks.rs) has slots of leaf ranks, mapped to vertices
// here: word 0 of `rank_blocks` is the block count (0: slots hold vertices), then a word per
// block of RANK_BLOCK ranks, either UNIFORM | the vertex of the whole block or the index of
// the block's own words in `rank_words`.
@group(0) @binding(6) var<storage, read> rank_blocks: array<u32>;
@group(0) @binding(7) var<storage, read> rank_words: array<u32>;

const RANK_BLOCK_SHIFT: u32 = 8u;
const UNIFORM: u32 = 0x80000000u;

fn vertex_of_rank(rank: u32) -> u32 {
    let word = rank_blocks[1u + (rank >> RANK_BLOCK_SHIFT)];
    if ((word & UNIFORM) != 0u) {
        return word & ~UNIFORM;
    }
    return rank_words[(word << RANK_BLOCK_SHIFT) + (rank & ((1u << RANK_BLOCK_SHIFT) - 1u))];
}

const PART_HIDDEN: u32 = 1u;
const PART_PICKED: u32 = 2u;

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
    @location(4) @interpolate(flat) part: u32,
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

// The look of a part: its table entry, or none (palette colour, shown) past the table.
fn part_look(part: u32) -> vec2<u32> {
    if (part < frame.part_count) {
        return parts[part];
    }
    return vec2<u32>(0u, 0u);
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
    var slot = slots[index / 3u];
    if (rank_blocks[0] != 0u && slot.x != 0xFFFFFFFFu) {
        slot = vec4<u32>(vertex_of_rank(slot.x), vertex_of_rank(slot.y), vertex_of_rank(slot.z), slot.w);
    }
    let k = index % 3u;
    out.barycentric = vec3<f32>(f32(k == 0u), f32(k == 1u), f32(k == 2u));
    let look = part_look(slot.w);
    // A triangle with a corner node entirely off-screen is off-screen at full detail: do not
    // draw its coarse stand-in (see `Style::cull_outside`). All three vertices decide alike.
    let culled = frame.cull_outside != 0u && slot.x != 0xFFFFFFFFu
        && (outside(node_spheres[slot.x]) || outside(node_spheres[slot.y]) || outside(node_spheres[slot.z]));
    if (slot.x == 0xFFFFFFFFu || culled || (look.y & PART_HIDDEN) != 0u) {
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
        let file = unpack4x8unorm(look.x);
        if (frame.colouring == 3u && file.a > 0.0) {
            out.colour = file.rgb;
        } else {
            out.colour = part_colour(slot.w);
        }
    }
    if ((look.y & PART_PICKED) != 0u) {
        // The picked part: pulled towards a saturated orange, still shaded.
        out.colour = mix(out.colour, vec3<f32>(1.0, 0.45, 0.05), 0.65);
    }
    out.part = slot.w;
    return out;
}

// True when a section plane cuts `world` away.
fn sectioned(world: vec3<f32>) -> bool {
    for (var i = 0u; i < frame.section_count; i = i + 1u) {
        let plane = frame.sections[i];
        if (dot(plane.xyz, world) + plane.w > 0.0) {
            return true;
        }
    }
    return false;
}

@fragment
fn fs_main(in: VertexOut, @builtin(front_facing) front: bool) -> @location(0) vec4<f32> {
    if (sectioned(in.world)) {
        discard;
    }
    if (frame.section_count > 0u && !front) {
        // Inside a sectioned solid: a flat, darker cap colour, unlit, so the section's
        // outline reads as a solid face. (Winding decides what is inside: CAD exports wind
        // solids outwards; soup with mixed winding shows some caps on outer faces.)
        return vec4<f32>(in.colour * 0.45, 1.0);
    }
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

// The picking pass: the part id (plus one; 0 is the background) and the world position of
// the frontmost drawn fragment, under the same visibility rules as `fs_main`.
@fragment
fn fs_pick(in: VertexOut) -> @location(0) vec4<u32> {
    if (sectioned(in.world)) {
        discard;
    }
    return vec4<u32>(in.part + 1u, bitcast<u32>(in.world.x), bitcast<u32>(in.world.y), bitcast<u32>(in.world.z));
}
