/* The renderer's GLSL 4.50 sources. Loops over fragments index sampler arrays with the loop
 * counter (dynamically uniform, allowed from GLSL 4.0) and hold no break or continue: llvmpipe
 * once mis-ran those inside a per-volume inner loop. */
#include "render_impl.h"

/* A triangle that covers the viewport. */
const char *const render__quad_vs =
    "#version 450 core\n"
    "void main() {\n"
    "    vec2 p = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2);\n"
    "    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);\n"
    "}\n";

/* The raycaster's triangle: the same, at depth 1, so that a depth test of GREATER passes only
 * where a brick was drawn into the depth buffer (draw_raycast). */
const char *const render__ray_vs =
    "#version 450 core\n"
    "void main() {\n"
    "    vec2 p = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2);\n"
    "    gl_Position = vec4(p * 2.0 - 1.0, 1.0, 1.0);\n"
    "}\n";

/* The raycaster's bricks: the occupied bricks' boundary faces of each fragment, placed by its
 * model matrix and drawn with MIN (then MAX) blending into channel `comp` of a layer of span_tex:
 * per pixel and fragment, the nearest and farthest occupied brick. Orthographic, so window depth
 * is the ray's parameter over its length; each ray samples a fragment only inside its span, and
 * pixels that no brick covers cost a few texel fetches. */
const char *const render__proxy_vs =
    "#version 450 core\n"
    "layout(location = 0) in vec3 pos;\n"
    "uniform mat4 vp, model;\n"
    "void main() { gl_Position = vp * model * vec4(pos, 1.0); }\n";

const char *const render__depth_fs =
    "#version 450 core\n"
    "uniform int comp;\n"
    "uniform float fill;\n"
    "out vec4 frag_colour;\n"
    "void main() { vec4 v = vec4(fill); v[comp] = gl_FragCoord.z; frag_colour = v; }\n";

/* The contacts colour (render.h), shared by the surface and the raycaster, after "#define NF":
 * gap_to(j, tc), the gap (mm) from the point at texture coordinates tc of fragment j to fragment
 * j's voxels, from its distance map (beyond its outer voxel centres the distance to the nearest of
 * them added; less half a voxel, dist_off[j], as its surface lies about there); gap_ramp, its
 * colour: ramp[0] at 0, ramp[1] at gap_scale / 2, the bone's own colour from gap_scale. */
#define GAP_GLSL \
    "uniform sampler3D dist[NF];\n" \
    "uniform vec3 box_mm[NF];\n" \
    "uniform float dist_off[NF];\n" \
    "uniform vec3 ramp[2];\n" \
    "uniform float gap_scale;\n" \
    "float gap_to(int j, vec3 tc) {\n" \
    "    vec3 edge = 0.5 / vec3(textureSize(dist[j], 0)), in_box = clamp(tc, edge, 1.0 - edge);\n" \
    "    return texture(dist[j], in_box).r + length((tc - in_box) * box_mm[j]) - dist_off[j];\n" \
    "}\n" \
    "vec3 gap_ramp(float gap, vec3 bone) {\n" \
    "    float h = 0.5 * gap_scale, g = max(gap, 0.0);\n" \
    "    return g < h ? mix(ramp[0], ramp[1], g / h) : g < gap_scale ? mix(ramp[1], bone, (g - h) / h) : bone;\n" \
    "}\n"

/* The cut-away (render_options.cutaway): another fragment's surface inside the cylinder of radius
 * cut.w from the kept fragment's centroid cut.xyz towards the viewer, and in front of the kept
 * fragment's nearest corner (cut_front along forward, from the centroid), is not drawn. */
#define CUTAWAY_GLSL \
    "uniform vec4 cut;\n" \
    "uniform float cut_front;\n" \
    "bool cut_away(vec3 p, vec3 forward) {\n" \
    "    vec3 d = p - cut.xyz;\n" \
    "    float along = dot(d, forward);\n" \
    "    return cut.w > 0.0 && along < cut_front && length(d - along * forward) < cut.w;\n" \
    "}\n"

/* The raycaster. Every fragment's ray is o[i] + d[i] * t in its texture coordinates, with t the
 * same world distance for all, so one march visits every fragment at once. It is compiled per
 * scene and mode after "#version 450 core", "#define NF <fragments>", "#define mode <0 iso,
 * 1 dvr, 2 mip>", "#define GAPS <0, or 1: iso with the contacts colour at the hit (GAP_GLSL)>" and
 * "#define CUT <0, or 1: iso skips the samples of the fragments but cut_keep inside the cut-away>"
 * (llvmpipe runs both sides of a branch its lanes disagree on, so code for the
 * other modes would cost every step): with a constant count the loops
 * unroll and the per-ray arrays stay in registers (llvmpipe lowers a dynamically indexed local
 * array to a select over all its elements, so 16 slots for 3 fragments cost 2 to 4 times as much).
 * In iso mode the march is two inner loops, coarse steps (occupancy fetches only) until a fragment's
 * block is occupied, then fine steps (volume fetches only) to fine_end: llvmpipe runs every
 * statement of a loop body for all lanes, so one body doing both paid for both kinds of fetch at
 * every step. The steps are the same as the one loop of dvr and mip takes. */
const char *const render__ray_fs =
    "#define MAXF NF\n"
    "#define nfrag NF\n"
    "uniform mat4 inv_vp;\n"
    "uniform vec4 viewport;\n"
    "uniform mat4 w2t[MAXF];\n"
    "uniform mat3 nmat[MAXF];\n"
    "uniform vec3 colour[MAXF];\n"
    "uniform vec3 occ_scale[MAXF];\n"
    "uniform ivec4 occ_info[MAXF];\n"
    "uniform sampler3D vol[MAXF];\n"
    "uniform usampler3D occ;\n"
    "uniform sampler1D tf;\n"
    "uniform vec2 tf_range;\n"
    "uniform float iso, step_fine, step_coarse, entry_skip;\n"
    "uniform vec3 bg;\n"
    "uniform sampler2DArray near_depth, far_depth;\n"
    "uniform int cut_keep;\n" /* the cut-away's kept fragment (cut, CUTAWAY_GLSL), -1: none */
    "out vec4 frag_colour;\n"
    "vec3 o[MAXF]; vec3 d[MAXF]; float tn[MAXF]; float tx[MAXF];\n"
    "vec3 ray_o, ray_d;\n" /* the ray in world mm: ray_o + ray_d * t */
    CUTAWAY_GLSL
    "#if GAPS\n"
    GAP_GLSL
    "#endif\n"
    "bool occupied(int i, vec3 p) {\n"
    "    ivec3 c = clamp(ivec3(p * occ_scale[i]), ivec3(0), occ_info[i].xyz - 1);\n"
    "    c.z += occ_info[i].w;\n"
    "    return texelFetch(occ, c, 0).r != 0u;\n"
    "}\n"
    "bool any_occupied(float t) {\n"
    "    bool any = false;\n"
    "    for (int i = 0; i < nfrag; ++i)\n"
    "        any = any || (t >= tn[i] && t <= tx[i] && occupied(i, o[i] + d[i] * t));\n"
    "    return any;\n"
    "}\n"
    "float sample_max(float t, out int best) {\n"
    "    float m = -4000.0; best = -1;\n"
    "#if CUT\n"
    "    bool cut_here = cut_away(ray_o + ray_d * t, ray_d);\n" /* the others are cut away here */
    "#else\n"
    "    const bool cut_here = false;\n"
    "#endif\n"
    "    for (int i = 0; i < nfrag; ++i) {\n"
    "        vec3 p = o[i] + d[i] * t;\n"
    "        if (t >= tn[i] && t <= tx[i] && (i == cut_keep || !cut_here)) {\n"
    "            float v = texture(vol[i], p).r;\n"
    "            if (v > m) { m = v; best = i; }\n"
    "        }\n"
    "    }\n"
    "    return m;\n"
    "}\n"
    "vec3 shade_hit(float t, int f, vec3 rd) {\n"
    "    vec3 n = vec3(0.0, 0.0, 1.0); vec3 c = vec3(1.0);\n"
    "    for (int i = 0; i < nfrag; ++i) {\n"
    "        if (i == f) {\n"
    "            vec3 p = o[i] + d[i] * t; vec3 h = 1.0 / vec3(textureSize(vol[i], 0));\n"
    "            vec3 g = vec3(texture(vol[i], p + vec3(h.x, 0, 0)).r - texture(vol[i], p - vec3(h.x, 0, 0)).r,\n"
    "                          texture(vol[i], p + vec3(0, h.y, 0)).r - texture(vol[i], p - vec3(0, h.y, 0)).r,\n"
    "                          texture(vol[i], p + vec3(0, 0, h.z)).r - texture(vol[i], p - vec3(0, 0, h.z)).r);\n"
    "            n = nmat[i] * g; c = colour[i];\n"
    "        }\n"
    "    }\n"
    "#if GAPS\n" /* the gap from the hit on fragment f to the others */
    "    float gap = 1e30;\n"
    "    for (int j = 0; j < nfrag; ++j) { float g = gap_to(j, o[j] + d[j] * t); gap = j == f ? gap : min(gap, g); }\n"
    "    c = gap_ramp(gap, c);\n"
    "#endif\n"
    "    float len = length(n);\n"
    "    float diff = len > 0.0 ? abs(dot(n / len, rd)) : 1.0;\n"
    "    return c * (0.2 + 0.8 * diff) + vec3(0.25 * pow(diff, 24.0));\n"
    "}\n"
    "void main() {\n"
    "    frag_colour = vec4(bg, 1.0);\n"
    "    vec2 ndc = (gl_FragCoord.xy - viewport.xy) / viewport.zw * 2.0 - 1.0;\n"
    "    vec4 a = inv_vp * vec4(ndc, -1.0, 1.0), b = inv_vp * vec4(ndc, 1.0, 1.0);\n"
    "    vec3 ro = a.xyz / a.w, re = b.xyz / b.w;\n"
    "    float len = length(re - ro); vec3 rd = (re - ro) / len;\n"
    "    ray_o = ro; ray_d = rd;\n"
    "    float t0 = 1e30, t1 = -1e30;\n"
    "    for (int i = 0; i < nfrag; ++i) {\n"
    "        o[i] = (w2t[i] * vec4(ro, 1.0)).xyz; d[i] = mat3(w2t[i]) * rd;\n"
    "        vec3 dd = mix(d[i], vec3(1e-12), lessThan(abs(d[i]), vec3(1e-12)));\n"
    "        vec3 ta = -o[i] / dd, tb = (1.0 - o[i]) / dd;\n"
    "        vec3 lo = min(ta, tb), hi = max(ta, tb);\n"
    "        ivec3 px = ivec3(ivec2(gl_FragCoord.xy), i >> 2);\n"
    "        float zn = texelFetch(near_depth, px, 0)[i & 3], zf = texelFetch(far_depth, px, 0)[i & 3];\n"
    "        tn[i] = max(max(lo.x, lo.y), max(lo.z, max(zn - 0.002, 0.0) * len));\n" /* RGBA16F: a margin */
    "        tx[i] = min(min(hi.x, hi.y), min(hi.z, min(zf + 0.002, 1.0) * len));\n"
    "        if (zn >= 1.0) tx[i] = -1e30;\n"
    "        if (tn[i] <= tx[i]) { t0 = min(t0, tn[i]); t1 = max(t1, tx[i]); }\n"
    "        else { tn[i] = 1e30; tx[i] = -1e30; }\n"
    "    }\n"
    "    if (t0 > t1) return;\n"
    "    float t = t0, prev = t0, fine_end = -1.0;\n"
    "    vec4 acc = vec4(0.0); float vmax = -4000.0; int fmax = -1;\n"
    "    bool done = false, prev_empty = true; int hit = -1;\n"
    "#if mode == 0\n"
    "    int s = 0;\n"
    "    while (s < 8192 && t <= t1 && !done) {\n"
    "        while (s < 8192 && t <= t1 && !any_occupied(t)) { prev = t; prev_empty = true; t += step_coarse; ++s; }\n"
    "        if (s < 8192 && t <= t1) { fine_end = t + step_coarse; t = prev_empty ? min(prev + entry_skip, t) : prev; }\n"
    "        while (s < 8192 && t <= t1 && t <= fine_end && !done) {\n"
    "            int f; float v = sample_max(t, f);\n"
    "            if (v >= iso) { hit = f; done = true; }\n"
    "            else { if (v > iso - 400.0) fine_end = max(fine_end, t + step_coarse); prev = t; prev_empty = false; t += step_fine; }\n"
    "            ++s;\n"
    "        }\n"
    "    }\n"
    "#else\n"
    "    for (int s = 0; s < 8192 && t <= t1 && !done; ++s) {\n"
    "        bool fine = t <= fine_end;\n"
    "        if (!fine && any_occupied(t)) {\n" /* re-march the last coarse step finely */
    "            fine_end = t + step_coarse; t = prev_empty ? min(prev + entry_skip, t) : prev; fine = true;\n"
    "        }\n"
    "        if (!fine) { prev = t; prev_empty = true; t += step_coarse; }\n"
    "        else if (mode == 0) {\n"
    "            int f; float v = sample_max(t, f);\n"
    "            if (v >= iso) { hit = f; done = true; }\n"
    "            else { if (v > iso - 400.0) fine_end = max(fine_end, t + step_coarse); prev = t; prev_empty = false; t += step_fine; }\n"
    "        } else {\n"
    "            bool inside = false;\n"
    "            for (int i = 0; i < nfrag; ++i) {\n"
    "                if (t >= tn[i] && t <= tx[i]) {\n"
    "                    float v = texture(vol[i], o[i] + d[i] * t).r;\n"
    "                    inside = inside || v >= iso;\n"
    "                    if (v > vmax) { vmax = v; fmax = i; }\n"
    "                    vec4 c = texture(tf, (v - tf_range.x) / (tf_range.y - tf_range.x));\n"
    "                    float al = mode == 1 ? c.a : 0.0;\n"
    "                    acc.rgb += (1.0 - acc.a) * al * c.rgb * colour[i];\n"
    "                    acc.a += (1.0 - acc.a) * al;\n"
    "                }\n"
    "            }\n"
    "            if (inside) fine_end = max(fine_end, t + step_coarse);\n"
    "            done = acc.a > 0.98;\n"
    "            prev = t; prev_empty = false; t += step_fine;\n"
    "        }\n"
    "    }\n"    "#endif\n"
    "    if (mode == 0) {\n"
    "        if (hit < 0) return;\n"
    "        float lo = prev, hi = t;\n"
    "        for (int k = 0; k < 6; ++k) {\n"
    "            float mid = 0.5 * (lo + hi); int f; float v = sample_max(mid, f);\n"
    "            if (v >= iso) { hi = mid; hit = f; } else lo = mid;\n"
    "        }\n"
    "        frag_colour = vec4(shade_hit(hi, hit, rd), 1.0);\n"
    "    } else if (mode == 1) {\n"
    "        frag_colour = vec4(acc.rgb + (1.0 - acc.a) * bg, 1.0);\n"
    "    } else if (fmax >= 0 && vmax >= iso) {\n"
    "        float k = clamp((vmax - tf_range.x) / (tf_range.y - tf_range.x), 0.0, 1.0);\n"
    "        vec3 c = vec3(1.0);\n"
    "        for (int i = 0; i < nfrag; ++i) c = i == fmax ? colour[i] : c;\n"
    "        frag_colour = vec4(mix(bg, c, 0.15 + 0.85 * k), 1.0);\n"
    "    }\n"
    "}\n";

/* A slice: the plane point p = centre + u * ndc.x + v * ndc.y; outlines where a fragment's mask
 * differs one pixel away. */
const char *const render__slice_fs =
    "#version 450 core\n"
    "#define MAXF 16\n"
    "uniform int nfrag, have_ct;\n"
    "uniform vec4 viewport;\n"
    "uniform vec3 centre, axis_u, axis_v;\n"
    "uniform mat4 w2t[MAXF];\n"
    "uniform vec3 colour[MAXF];\n"
    "uniform sampler3D vol[MAXF];\n"
    "uniform sampler3D ct;\n"
    "uniform mat4 ct_w2t;\n"
    "uniform vec2 window;\n"
    "uniform float iso;\n"
    "uniform vec3 bg;\n"
    "out vec4 frag_colour;\n"
    "bool inside(int i, vec3 p) {\n"
    "    vec3 tc = (w2t[i] * vec4(p, 1.0)).xyz;\n"
    "    bool in_box = all(greaterThanEqual(tc, vec3(0.0))) && all(lessThanEqual(tc, vec3(1.0)));\n"
    "    return in_box && texture(vol[i], tc).r >= iso;\n"
    "}\n"
    "void main() {\n"
    "    vec2 ndc = (gl_FragCoord.xy - viewport.xy) / viewport.zw * 2.0 - 1.0;\n"
    "    vec3 p = centre + axis_u * ndc.x + axis_v * ndc.y;\n"
    "    vec3 du = axis_u * 2.0 / viewport.z, dv = axis_v * 2.0 / viewport.w;\n"
    "    vec3 c = bg;\n"
    "    if (have_ct != 0) {\n"
    "        vec3 tc = (ct_w2t * vec4(p, 1.0)).xyz;\n"
    "        if (all(greaterThanEqual(tc, vec3(0.0))) && all(lessThanEqual(tc, vec3(1.0))))\n"
    "            c = vec3(clamp((texture(ct, tc).r - window.x) / (window.y - window.x), 0.0, 1.0));\n"
    "    }\n"
    "    for (int i = 0; i < nfrag; ++i) {\n"
    "        bool a = inside(i, p);\n"
    "        bool edge = a != inside(i, p + du) || a != inside(i, p + dv);\n"
    "        c = edge ? colour[i] : (a ? mix(c, colour[i], 0.2) : c);\n"
    "    }\n"
    "    frag_colour = vec4(c, 1.0);\n"
    "}\n";

const char *const render__mesh_vs =
    "#version 450 core\n"
    "layout(location = 0) in vec3 pos;\n"
    "layout(location = 1) in vec3 nrm;\n"
    "uniform mat4 vp, model;\n"
    "out vec3 n_world, p_world;\n"
    "void main() {\n"
    "    n_world = mat3(model) * nrm;\n"
    "    p_world = (model * vec4(pos, 1.0)).xyz;\n"
    "    gl_Position = vp * model * vec4(pos, 1.0);\n"
    "}\n";


/* After "#version 450 core" and "#define NF <n>": with NF 0 the shaded surface; with NF > 0
 * (compiled per scene, render__gaps_program, so the loop unrolls and its samplers are fixed) the
 * contacts colour too (GAP_GLSL): the gap from this point to the nearest of the NF other fragments
 * (all but the one drawn; texture coordinates w2t[j]). */
const char *const render__mesh_fs =
    "uniform vec3 colour, forward;\n"
    "uniform float alpha = 1.0;\n"
    "in vec3 n_world, p_world;\n"
    "out vec4 frag_colour;\n"
    CUTAWAY_GLSL
    "#if NF > 0\n"
    "uniform mat4 w2t[NF];\n"
    GAP_GLSL
    "vec3 gap_colour(vec3 bone) {\n"
    "    float gap = 1e30;\n"
    "    for (int j = 0; j < NF; ++j)\n"
    "        gap = min(gap, gap_to(j, (w2t[j] * vec4(p_world, 1.0)).xyz));\n"
    "    return gap_ramp(gap, bone);\n"
    "}\n"
    "#endif\n"
    "void main() {\n"
    "    if (cut_away(p_world, forward))\n"
    "        discard;\n"
    "#if NF > 0\n"
    "    vec3 c = gap_colour(colour);\n"
    "#else\n"
    "    vec3 c = colour;\n"
    "#endif\n"
    "    float len = length(n_world);\n"
    "    float diff = len > 0.0 ? abs(dot(n_world / len, forward)) : 1.0;\n"
    "    frag_colour = vec4(c * (0.2 + 0.8 * diff) + vec3(0.25 * pow(diff, 24.0)), alpha);\n"
    "}\n";

/* Fragment i's mesh in the flat colour (i + 1) / 255: which fragment is front-most where. */
const char *const render__id_fs =
    "#version 450 core\n"
    "uniform vec3 colour, forward;\n"
    "in vec3 p_world;\n"
    "out vec4 frag_colour;\n"
    CUTAWAY_GLSL
    "void main() {\n"
    "    if (cut_away(p_world, forward))\n"
    "        discard;\n"
    "    frag_colour = vec4(colour, 1.0);\n"
    "}\n";

const char *const render__line_vs =
    "#version 450 core\n"
    "layout(location = 0) in vec3 pos;\n"
    "layout(location = 1) in vec3 col;\n"
    "uniform mat4 vp, model;\n"
    "out vec3 c;\n"
    "void main() { c = col; gl_Position = vp * model * vec4(pos, 1.0); }\n";

const char *const render__line_fs =
    "#version 450 core\n"
    "uniform vec3 tint;\n"
    "uniform int use_tint;\n"
    "uniform float alpha;\n"
    "in vec3 c;\n"
    "out vec4 frag_colour;\n"
    "void main() { frag_colour = vec4(use_tint != 0 ? tint : c, alpha); }\n";

/* The HUD: its R8 texture (rows top to bottom from `origin`, the box's top-left pixel in window
 * coordinates) over the frame, inside the scissor box: 1 text, 0.5 warning text, 0 the box. */
const char *const render__hud_fs =
    "#version 450 core\n"
    "uniform sampler2D hud;\n"
    "uniform vec2 origin;\n"
    "out vec4 frag_colour;\n"
    "void main() {\n"
    "    ivec2 p = ivec2(int(gl_FragCoord.x - origin.x), int(origin.y - gl_FragCoord.y));\n"
    "    float v = texelFetch(hud, p, 0).r;\n"
    "    frag_colour = v > 0.75 ? vec4(0.92, 0.95, 1.0, 1.0)\n"
    "                : v > 0.25 ? vec4(1.0, 0.72, 0.1, 1.0) : vec4(0.0, 0.0, 0.0, 0.55);\n"
    "}\n";
