// A unit vector in 32 bits: two snorm16 octahedral coordinates (Cigolle et
// al. 2014, "A Survey of Efficient Representations for Independent Unit
// Vectors"), packed on the CPU by pack_unit_vector (gi/gpu/shader.h) into a
// float lane's bits: within 1e-4 rad of the vector packed.
#ifndef LF_UNIT_VECTOR_GLSL
#define LF_UNIT_VECTOR_GLSL

vec3 lf_unpack_unit_vector(float bits) {
    vec2 e = unpackSnorm2x16(floatBitsToUint(bits));
    vec3 v = vec3(e, 1.0 - abs(e.x) - abs(e.y));
    if (v.z < 0.0) v.xy = (1.0 - abs(v.yx)) * vec2(v.x >= 0.0 ? 1.0 : -1.0, v.y >= 0.0 ? 1.0 : -1.0);
    return normalize(v);
}

#endif
