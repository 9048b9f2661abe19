// Turning a checked tinygltf::Model into a Scene (internal to gi/scene).
//
//   place_nodes     gltf_nodes.cpp      node graph checks, scene roots, world transforms
//   add_materials   gltf_materials.cpp  materials and their (sRGB-decoded) textures
//   add_geometry    gltf_geometry.cpp   primitives -> world-space triangles
//   add_lights      gltf_materials.cpp  KHR_lights_punctual
#pragma once

#include "scene/gltf_accessors.h"
#include "scene/gltf_errors.h"
#include "scene/gltf_images.h"
#include "scene/scene.h"

#include <glm/glm.hpp>
#include <tiny_gltf.h>

#include <string>
#include <vector>

namespace lf::gltf {

// A node of the chosen scene that carries a mesh or a light, with its world transform.
struct PlacedNode {
    int node = -1;
    int item = -1;  // mesh index, or light index into Model::lights
    glm::dmat4 world{1.0};
};

struct Placement {
    std::vector<PlacedNode> meshes;
    std::vector<PlacedNode> lights;
    // Nodes whose extras say {"lightfarm_probe": true}: where a probe goes.
    std::vector<PlacedNode> probes;
};

// Checks the whole node graph (indices, transforms, a single parent per node,
// no cycles) and walks the default scene (else scene 0, else every root node).
Placement place_nodes(const tinygltf::Model& model, const Errors& errors, std::vector<std::string>* warnings);

// Scene::materials from the file's materials, in order; decodes the images
// they use (GLB-embedded ones here, the rest were decoded during parsing).
void add_materials(tinygltf::Model& model, const Errors& errors, ImageDecoder& images, const AccessorReader& reader,
                   Scene& scene, std::vector<std::string>* warnings);

// Every triangle primitive of every placed mesh, in world space. Appends a
// default white material if a primitive has none.
void add_geometry(const tinygltf::Model& model, const std::vector<PlacedNode>& meshes, const AccessorReader& reader,
                  const LoadLimits& limits, const Errors& errors, Scene& scene, std::vector<std::string>* warnings);

void add_lights(const tinygltf::Model& model, const std::vector<PlacedNode>& lights, const Errors& errors, Scene& scene,
                std::vector<std::string>* warnings);

}  // namespace lf::gltf
