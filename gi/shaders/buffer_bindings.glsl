// Every shader storage buffer's binding point, for GLSL and C++ alike: a
// shader declares `layout(std430, binding = LF_BINDING_X)` and the C++ that
// runs it binds `buffer.bind(LF_BINDING_X)`, so each number is written once.
// Only #defines: C++ includes it as "shaders/buffer_bindings.glsl".
//
// Numbers are reused between programs that never run together: each group
// below is one family of programs (a group's comment names its shaders).
#ifndef LF_BUFFER_BINDINGS_GLSL
#define LF_BUFFER_BINDINGS_GLSL

// A program's parameters: one uniform block per dispatch, std140, 4-byte
// scalars only (so C++ and GLSL agree on every offset), defined once for
// both languages in the program's *_params.glsl and set by
// ComputeProgram::use(params). Uniform-buffer bindings are apart from the
// storage buffers' below; this is the only one.
#define LF_BINDING_PARAMS 0

// The scene's BVH (trace.glsl), bound by Tracer::bind() for every program that traces.
#define LF_BINDING_BVH_NODES 0
#define LF_BINDING_BVH_TRIANGLES 1

// A radiosity-map bake's texels (radiosity_texels.glsl, lightmap_lookup.glsl,
// radiosity_resolve.glsl, radiosity_gather.comp, radiosity_totals.comp,
// radiosity_publish.comp, texel_*.comp, copy_texels.comp).
#define LF_BINDING_TEXEL_SAMPLE_POINTS 2
#define LF_BINDING_COVERED_TEXELS 3
#define LF_BINDING_TEXEL_ACCUMULATORS 4
#define LF_BINDING_REFLECTED_RADIANCE 5  // per atlas texel
#define LF_BINDING_ATLAS_TEXELS 5        // copy_texels.comp: whichever per-atlas-texel buffer is dilated
#define LF_BINDING_ERROR_PARTIALS 9
#define LF_BINDING_COPY_PAIRS 10
#define LF_BINDING_TEXEL_ANCHORS 11
#define LF_BINDING_TEXEL_ALBEDO 15
#define LF_BINDING_DIRECTIONAL_ACCUMULATORS 16
#define LF_BINDING_REFLECTED_INDIRECT 19  // per atlas texel, under a final gather
#define LF_BINDING_MOVED_SAMPLES 20       // texel_relocate.comp, texel_anchor.comp: a bit per sample point
#define LF_BINDING_TEXEL_TOTALS 21        // per pass of a dispatch and covered texel (radiosity_gather.comp, radiosity_totals.comp)
// The record of one covered texel in LF_BINDING_TEXEL_ACCUMULATORS: this
// many vec4s, at these offsets (radiosity_texels.glsl says what each sums).
#define LF_TEXEL_ACCUMULATORS 5u
#define LF_ACC_DIRECT 0u
#define LF_ACC_MOMENTS 1u
#define LF_ACC_INDIRECT 2u
#define LF_ACC_PREVIOUS 3u
#define LF_ACC_ALBEDO 4u
// What an atlas texel is, in w of LF_BINDING_TEXEL_ANCHORS (read back by
// RadiosityMapBaker to count the texels geometry touched).
#define LF_ANCHOR_UNCOVERED 0.0
#define LF_ANCHOR_COVERED 1.0
#define LF_ANCHOR_CUT 2.0          // its samples were on both sides of geometry (texel_anchor.comp)
#define LF_ANCHOR_NEXT_TO_CUT 3.0  // a wall between it and a neighbour's anchor (texel_wall_check.comp)

// The scene's surfaces and lights (SceneShading: lightmap_lookup.glsl,
// direct_light.glsl) and their textures (SurfaceTextures: surface_textures.glsl).
#define LF_BINDING_SURFACE_TRIANGLES 6
// A surface triangle's flag bits (its second vec4's z, lightmap_lookup.glsl).
#define LF_TRIANGLE_DOUBLE_SIDED 1u
#define LF_TRIANGLE_WITHOUT_LIGHTMAP 2u  // its mesh has no lightmap of its own (lightmap scale 0)
#define LF_BINDING_EMITTERS 7
#define LF_BINDING_PUNCTUAL_LIGHTS 8
#define LF_BINDING_SURFACE_TEXCOORDS 17
#define LF_BINDING_MATERIAL_TEXTURES 18
// The environment's equirectangular texels (environment.glsl,
// EnvironmentLight): a buffer texture, at this texture unit (the only one).
#define LF_TEXTURE_ENVIRONMENT 0

// The probes' capture (probe_capture.comp, probe_corners.comp), beside the scene's shading.
#define LF_BINDING_PROBE_POSITIONS 12
#define LF_BINDING_PROBE_TEXELS 13
#define LF_BINDING_PROBE_RAYS 14
#define LF_BINDING_PROBE_CORNERS 22  // probe_corners.comp

// SH transfer (sh_transfer.comp, sh_resolve.comp) and its reference (sh_reference.comp).
#define LF_BINDING_SH_VERTICES 2
#define LF_BINDING_SH_ACCUMULATORS 3
#define LF_BINDING_SH_RESOLVED 4
#define LF_BINDING_SH_TRIANGLE_IDS 5
#define LF_BINDING_SH_TRIANGLE_ALBEDO 6
#define LF_BINDING_SH_ERROR_PARTIALS 7
#define LF_BINDING_IRRADIANCE 4  // sh_reference.comp

// Rays and hits through the tracer (trace_rays.comp, raybench.comp).
#define LF_BINDING_RAYS 2
#define LF_BINDING_HITS 3
#define LF_BINDING_SURFACE_POINTS 2  // raybench.comp
#define LF_BINDING_HIT_COUNTS 3      // raybench.comp

// Ambient occlusion (ambient_occlusion.comp): its sample points and counts.
#define LF_BINDING_AO_POINTS 3
#define LF_BINDING_AO_UNOCCLUDED 4

// The lightmap denoiser (lightmap_denoise.comp).
#define LF_BINDING_DENOISE_GUIDE 0
#define LF_BINDING_DENOISE_IN 1
#define LF_BINDING_DENOISE_OUT 2
#define LF_BINDING_DENOISE_KEEP 3  // per texel: 1 where the bake is sure of its value (LightmapDenoiser)

// Checks that run GLSL on inputs from C++ (probe_eval_check.comp,
// surface_texture_check.comp, dispatch_check.comp): cases in, results out.
#define LF_BINDING_PROBE_SET 0  // probe_eval.glsl's probe texels
#define LF_BINDING_CHECK_CASES 1
#define LF_BINDING_CHECK_RESULTS 2
#define LF_BINDING_ITEM_VISITS 0  // dispatch_check.comp
#define LF_BINDING_GROUP_SLOTS 1  // dispatch_check.comp

#endif
