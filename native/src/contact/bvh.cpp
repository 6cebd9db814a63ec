#include "contact/bvh.h"

#include <algorithm>

namespace hh {

void Bvh::build(const std::vector<Aabb>& boxes) {
    nodes_.clear();
    if (boxes.empty()) return;
    std::vector<Vec3> centres(boxes.size());
    for (size_t i = 0; i < boxes.size(); ++i) centres[i] = 0.5 * (boxes[i].lo + boxes[i].hi);
    std::vector<int> items(boxes.size());
    for (size_t i = 0; i < items.size(); ++i) items[i] = static_cast<int>(i);
    nodes_.reserve(2 * boxes.size());
    build_range(items, 0, static_cast<int>(items.size()), centres, boxes);
}

int Bvh::build_range(std::vector<int>& items, int begin, int end, const std::vector<Vec3>& centres,
                     const std::vector<Aabb>& boxes) {
    const int index = static_cast<int>(nodes_.size());
    nodes_.emplace_back();
    if (end - begin == 1) {
        nodes_[index].item = items[begin];
        nodes_[index].box = boxes[items[begin]];
        return index;
    }
    Aabb spread;
    for (int i = begin; i < end; ++i) spread.grow(centres[items[i]]);
    int axis;
    (spread.hi - spread.lo).maxCoeff(&axis);
    const int mid = (begin + end) / 2;
    std::nth_element(items.begin() + begin, items.begin() + mid, items.begin() + end,
                     [&](int a, int b) { return centres[a][axis] < centres[b][axis]; });
    // depth stays about log2(items) thanks to the median split, far below the query stack
    const int left = build_range(items, begin, mid, centres, boxes);
    const int right = build_range(items, mid, end, centres, boxes);
    nodes_[index].left = left;
    nodes_[index].right = right;
    nodes_[index].box = nodes_[left].box;
    nodes_[index].box.grow(nodes_[right].box);
    return index;
}

void Bvh::refit(const std::vector<Aabb>& boxes) {
    // children always come after their parent, so a reverse sweep sees children first
    for (int i = static_cast<int>(nodes_.size()) - 1; i >= 0; --i) {
        Node& n = nodes_[i];
        if (n.item >= 0) {
            n.box = boxes[n.item];
        } else {
            n.box = nodes_[n.left].box;
            n.box.grow(nodes_[n.right].box);
        }
    }
}

}  // namespace hh
