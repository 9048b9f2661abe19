// The node hierarchy: checked as a whole before it is walked, so that a cycle
// or a shared child is an error rather than endless recursion or a mesh placed
// twice, and walked with an explicit stack (no recursion on file depth).
#include "scene/gltf_build.h"

#include <glm/gtc/matrix_transform.hpp>
#include <glm/gtc/quaternion.hpp>
#include <glm/gtc/type_ptr.hpp>

#include <algorithm>
#include <cmath>

namespace lf::gltf {

namespace {

bool all_finite(const std::vector<double>& values) {
    for (double v : values) {
        if (!std::isfinite(v)) return false;
    }
    return true;
}

// The node's local transform, from its matrix or its translation, rotation and scale.
glm::dmat4 local_transform(const tinygltf::Node& node, int index, const Errors& errors) {
    const bool has_trs = !node.translation.empty() || !node.rotation.empty() || !node.scale.empty();
    auto check_size = [&](const std::vector<double>& v, size_t n, const char* what) {
        if (!v.empty() && v.size() != n)
            errors.fail("node", index,
                        std::string(what) + " has " + std::to_string(v.size()) + " values, not " + std::to_string(n));
        if (!all_finite(v)) errors.fail("node", index, std::string(what) + " is not finite");
    };
    check_size(node.matrix, 16, "matrix");
    check_size(node.translation, 3, "translation");
    check_size(node.rotation, 4, "rotation");
    check_size(node.scale, 3, "scale");

    if (!node.matrix.empty()) {
        if (has_trs) errors.fail("node", index, "has both a matrix and translation/rotation/scale");
        return glm::make_mat4(node.matrix.data());  // column-major, as glTF stores it
    }
    glm::dmat4 m(1.0);
    if (!node.translation.empty())
        m[3] = glm::dvec4(node.translation[0], node.translation[1], node.translation[2], 1.0);
    if (!node.rotation.empty()) {
        // glTF stores x, y, z, w; glm's constructor takes w first.
        glm::dquat q(node.rotation[3], node.rotation[0], node.rotation[1], node.rotation[2]);
        const double length = glm::length(q);
        if (!(length > 1e-12)) errors.fail("node", index, "rotation is not a unit quaternion (length 0)");
        m = m * glm::mat4_cast(q / length);
    }
    if (!node.scale.empty())
        m = m * glm::scale(glm::dmat4(1.0), glm::dvec3(node.scale[0], node.scale[1], node.scale[2]));
    return m;
}

// The KHR_lights_punctual light a node carries, or -1.
int node_light(const tinygltf::Node& node, int index, size_t light_count, const Errors& errors) {
    const auto it = node.extensions.find("KHR_lights_punctual");
    if (it == node.extensions.end()) return -1;
    const tinygltf::Value& ext = it->second;
    if (!ext.IsObject() || !ext.Has("light") || !ext.Get("light").IsInt())
        errors.fail("node", index, "KHR_lights_punctual has no integer light index");
    const int light = ext.Get("light").GetNumberAsInt();
    if (light < 0 || size_t(light) >= light_count) {
        errors.fail("node", index,
                    "light " + std::to_string(light) + " does not exist (the file has " + std::to_string(light_count) +
                        " lights)");
    }
    return light;
}

// parent[n] for every node, after checking child indices, self-children and
// shared children; then every node must hang below a parentless node, or it
// sits on a cycle.
std::vector<int> check_hierarchy(const tinygltf::Model& model, const Errors& errors) {
    const size_t n = model.nodes.size();
    std::vector<int> parent(n, -1);
    for (size_t i = 0; i < n; ++i) {
        for (int child : model.nodes[i].children) {
            if (child < 0 || size_t(child) >= n) {
                errors.fail("node", int64_t(i),
                            "child " + std::to_string(child) + " does not exist (the file has " + std::to_string(n) +
                                " nodes)");
            }
            if (size_t(child) == i) errors.fail("node", int64_t(i), "is its own child (a cycle in the node hierarchy)");
            if (parent[size_t(child)] != -1) {
                errors.fail("node", child,
                            "has two parents, node " + std::to_string(parent[size_t(child)]) + " and node " +
                                std::to_string(i) + " (glTF nodes form a tree)");
            }
            parent[size_t(child)] = int(i);
        }
    }
    // With at most one parent each, the nodes reachable from the parentless
    // ones are exactly those not on (or below) a cycle.
    std::vector<bool> reached(n, false);
    std::vector<size_t> stack;
    for (size_t i = 0; i < n; ++i) {
        if (parent[i] == -1) stack.push_back(i);
    }
    while (!stack.empty()) {
        const size_t i = stack.back();
        stack.pop_back();
        reached[i] = true;
        for (int child : model.nodes[i].children) stack.push_back(size_t(child));
    }
    for (size_t i = 0; i < n; ++i) {
        if (!reached[i]) {
            errors.fail("node", int64_t(i),
                        "is part of a cycle in the node hierarchy (its parent chain returns to itself)");
        }
    }
    return parent;
}

// The root nodes to walk: the default scene's, else scene 0's, else every parentless node.
std::vector<int> scene_roots(const tinygltf::Model& model, const std::vector<int>& parent, const Errors& errors) {
    std::vector<int> roots;
    int scene = model.defaultScene;
    if (scene >= 0 && size_t(scene) >= model.scenes.size()) {
        errors.fail("scene " + std::to_string(scene) + " (the default scene) does not exist (the file has " +
                    std::to_string(model.scenes.size()) + " scenes)");
    }
    if (scene < 0 && !model.scenes.empty()) scene = 0;
    if (scene < 0) {
        for (size_t i = 0; i < parent.size(); ++i) {
            if (parent[i] == -1) roots.push_back(int(i));
        }
        return roots;
    }
    std::vector<bool> listed(model.nodes.size(), false);
    for (int root : model.scenes[size_t(scene)].nodes) {
        if (root < 0 || size_t(root) >= model.nodes.size())
            errors.fail("scene", scene, "node " + std::to_string(root) + " does not exist");
        if (parent[size_t(root)] != -1) {
            errors.fail("scene", scene,
                        "node " + std::to_string(root) + " is listed as a root but is a child of node " +
                            std::to_string(parent[size_t(root)]));
        }
        if (listed[size_t(root)]) errors.fail("scene", scene, "lists node " + std::to_string(root) + " twice");
        listed[size_t(root)] = true;
        roots.push_back(root);
    }
    return roots;
}

}  // namespace

Placement place_nodes(const tinygltf::Model& model, const Errors& errors, std::vector<std::string>* warnings) {
    // Every node is checked, not only those of the chosen scene: a malformed
    // file is refused whichever scene it would show.
    std::vector<glm::dmat4> local(model.nodes.size());
    std::vector<int> lights(model.nodes.size(), -1);
    bool skinned = false;
    for (size_t i = 0; i < model.nodes.size(); ++i) {
        const tinygltf::Node& node = model.nodes[i];
        local[i] = local_transform(node, int(i), errors);
        if (node.mesh < -1 || (node.mesh >= 0 && size_t(node.mesh) >= model.meshes.size())) {
            errors.fail("node", int64_t(i),
                        "mesh " + std::to_string(node.mesh) + " does not exist (the file has " +
                            std::to_string(model.meshes.size()) + " meshes)");
        }
        lights[i] = node_light(node, int(i), model.lights.size(), errors);
        skinned = skinned || (node.skin >= 0 && node.mesh >= 0);
    }
    const std::vector<int> parent = check_hierarchy(model, errors);
    if (skinned) warnings->push_back("skins are ignored: skinned meshes are baked in their bind pose");

    Placement placement;
    std::vector<std::pair<int, glm::dmat4>> stack;
    for (int root : scene_roots(model, parent, errors)) stack.emplace_back(root, glm::dmat4(1.0));
    // Reverse so that nodes come out in file order of the roots (stack is LIFO).
    std::reverse(stack.begin(), stack.end());
    while (!stack.empty()) {
        const auto [index, parent_world] = stack.back();
        stack.pop_back();
        const tinygltf::Node& node = model.nodes[size_t(index)];
        const glm::dmat4 world = parent_world * local[size_t(index)];
        if (node.mesh >= 0) placement.meshes.push_back({index, node.mesh, world});
        if (lights[size_t(index)] >= 0) placement.lights.push_back({index, lights[size_t(index)], world});
        if (node.extras.IsObject() && node.extras.Has("lightfarm_probe") &&
            node.extras.Get("lightfarm_probe").IsBool() && node.extras.Get("lightfarm_probe").Get<bool>())
            placement.probes.push_back({index, -1, world});
        for (auto child = node.children.rbegin(); child != node.children.rend(); ++child)
            stack.emplace_back(*child, world);
    }
    return placement;
}

}  // namespace lf::gltf
