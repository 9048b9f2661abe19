// The light from beyond the scene: the radiance a ray that escapes sees
// (W/(sr m^2)), a uniform sky or an equirectangular map, nearest texel, in
// gi/sh/environment.h's convention (y up; the image's centre looks along +x):
//   u = 0.5 + atan(d.z, d.x) / (2 pi),  v = acos(d.y) / pi  (v = 0: the top row, looking up)
// The program's parameter block holds LF_ENVIRONMENT_PARAMS (params_block.glsl):
// the map's size (0 x 0: the uniform sky background_rgb) and, under a map,
// background_rgb scales it. Bound by EnvironmentLight.
#ifndef LF_ENVIRONMENT_GLSL
#define LF_ENVIRONMENT_GLSL

// A buffer texture, not a storage block: a compute program may have 16 of
// those (GL_MAX_COMPUTE_SHADER_STORAGE_BLOCKS, llvmpipe's and NVIDIA's), and
// the radiosity gather's variants use them all.
layout(binding = LF_TEXTURE_ENVIRONMENT) uniform samplerBuffer environment_texels;

vec3 lf_background_scale() { return vec3(background_r, background_g, background_b); }

// Whether escaping rays see any light (a sky ray is worth tracing).
bool lf_has_background() { return lf_background_scale() != vec3(0.0); }

// The radiance seen along the escaping direction d (unit length).
vec3 lf_background(vec3 d) {
    if (env_width == 0u) return lf_background_scale();
    float u = 0.5 + atan(d.z, d.x) / (2.0 * PI);
    float v = acos(clamp(d.y, -1.0, 1.0)) / PI;
    uint x = min(uint(u * float(env_width)), env_width - 1u);
    uint y = min(uint(v * float(env_height)), env_height - 1u);
    return lf_background_scale() * texelFetch(environment_texels, int(y * env_width + x)).rgb;
}

#endif
