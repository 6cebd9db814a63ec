// Broad phase: a bounding-volume hierarchy of axis-aligned boxes over a fixed set of items
// (surface triangles). Built once (median split), refitted every step as the surface moves.
#pragma once
#include <vector>

#include "contact/geometry.h"

namespace hh {

class Bvh {
public:
    void build(const std::vector<Aabb>& item_boxes);
    void refit(const std::vector<Aabb>& item_boxes);
    // Calls visit(item) for every item whose box overlaps query.
    template <class Visit>
    void query(const Aabb& query, Visit&& visit) const {
        if (nodes_.empty()) return;
        int stack[128];
        int top = 0;
        stack[top++] = 0;
        while (top > 0) {
            const Node& n = nodes_[stack[--top]];
            if (!n.box.overlaps(query)) continue;
            if (n.item >= 0) {
                visit(n.item);
            } else {
                stack[top++] = n.left;
                stack[top++] = n.right;
            }
        }
    }
    const Aabb& bounds() const { return nodes_.front().box; }
    bool empty() const { return nodes_.empty(); }

private:
    struct Node {
        Aabb box;
        int left = -1, right = -1, item = -1;  // item >= 0 for a leaf
    };
    int build_range(std::vector<int>& items, int begin, int end, const std::vector<Vec3>& centres,
                    const std::vector<Aabb>& boxes);
    std::vector<Node> nodes_;
};

}  // namespace hh
