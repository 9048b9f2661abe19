// The record of one material in the MaterialTextures buffer
// (surface_textures.glsl), for GLSL and C++ alike (SurfaceTextures writes
// it): LF_MATERIAL_UINTS uints from LF_MATERIALS_FIRST + LF_MATERIAL_UINTS x
// the material's index, each field at its offset. Only #defines: C++
// includes it as "shaders/material_layout.glsl".
#ifndef LF_MATERIAL_LAYOUT_GLSL
#define LF_MATERIAL_LAYOUT_GLSL

#define LF_MATERIALS_FIRST 2u  // after the material count and where the texture table starts
#define LF_MATERIAL_UINTS 16u
#define LF_MAT_BASE_COLOR 0u          // rgb, float bits
#define LF_MAT_EMISSION 3u            // rgb, float bits
#define LF_MAT_BASE_TEXTURE 6u        // texture + 1, 0: none
#define LF_MAT_EMISSIVE_TEXTURE 7u    // texture + 1, 0: none
#define LF_MAT_ALPHA 8u               // base colour alpha, float bits
#define LF_MAT_ALPHA_MODE 9u          // LF_ALPHA_*
#define LF_MAT_ALPHA_CUTOFF 10u       // float bits
#define LF_MAT_TRANSMISSION 11u       // KHR_materials_transmission's factor, float bits
#define LF_MAT_ATTENUATION 12u        // rgb, float bits: KHR_materials_volume's absorption per metre
#define LF_MAT_OPEN_THICKNESS 15u     // float bits: 0 for a closed volume, else the path each crossing absorbs over
// Material::AlphaMode.
#define LF_ALPHA_OPAQUE 0u
#define LF_ALPHA_MASK 1u
#define LF_ALPHA_BLEND 2u

#endif
