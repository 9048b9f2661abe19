// The BVH's shape, for GLSL and C++ alike (C++ includes it as
// "shaders/bvh_layout.glsl", as buffer_bindings.glsl): only #defines.
#ifndef LF_BVH_LAYOUT_GLSL
#define LF_BVH_LAYOUT_GLSL

// Children per node (trace/bvh.h's BvhNode: four boxes as vec4 components).
#define LF_BVH_WIDTH 4
// A node's size in uvec4: its box's corner and steps, the children's planes,
// their counts and their indices (BvhNode).
#define LF_BVH_NODE_UVEC4S 4
// The deepest the binary SAH tree may go; the wide tree collapsed from it is no deeper.
#define LF_BVH_MAX_DEPTH 48
// A traversal pushes at most LF_BVH_WIDTH - 1 nodes per level.
#define LF_BVH_STACK_SIZE ((LF_BVH_WIDTH - 1) * LF_BVH_MAX_DEPTH)

#endif
