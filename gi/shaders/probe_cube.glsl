// The probes' cube map convention (gi/probes/probe_set.h, cube_direction):
// faces +X, -X, +Y, -Y, +Z, -Z; face coordinates (u, v) in [0, 1]² with v
// growing down the face (rows from the top), as OpenGL's cube map table.
#ifndef LF_PROBE_CUBE_GLSL
#define LF_PROBE_CUBE_GLSL

// Unit direction through (u, v) of cube face `face` (0..5).
vec3 lf_cube_direction(int face, vec2 uv) {
    float s = 2.0 * uv.x - 1.0, t = 2.0 * uv.y - 1.0;
    vec3 d;
    if (face == 0) d = vec3(1.0, -t, -s);
    else if (face == 1) d = vec3(-1.0, -t, s);
    else if (face == 2) d = vec3(s, 1.0, t);
    else if (face == 3) d = vec3(s, -1.0, -t);
    else if (face == 4) d = vec3(s, -t, 1.0);
    else d = vec3(-s, -t, -1.0);
    return normalize(d);
}

#endif
