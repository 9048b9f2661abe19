// Random numbers: a PCG hash per (item, pass, dimension), so every sample is
// reproducible from the seed alone and no RNG state is stored between passes.
#ifndef LF_RANDOM_GLSL
#define LF_RANDOM_GLSL

// PCG-RXS-M-XS 32-bit hash (Jarzynski & Olano 2020, "Hash Functions for GPU Rendering").
uint pcg_hash(uint v) {
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

struct Rng { uint state; };

Rng rng_start(uint item, uint pass, uint seed) {
    return Rng(pcg_hash(item ^ pcg_hash(pass ^ pcg_hash(seed))));
}

// Uniform in [0, 1).
float rng_next(inout Rng rng) {
    rng.state = rng.state * 747796405u + 2891336453u;
    uint word = ((rng.state >> ((rng.state >> 28u) + 4u)) ^ rng.state) * 277803737u;
    word = (word >> 22u) ^ word;
    return float(word >> 8) * (1.0 / 16777216.0);
}

vec2 rng_next2(inout Rng rng) { return vec2(rng_next(rng), rng_next(rng)); }

#endif
