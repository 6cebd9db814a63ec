#include "contact/bvh.h"

#include <algorithm>

namespace hh {

namespace {

// The binary median-split tree with one item per leaf, as first built: only its shape and
// the order of its leaves are kept (ranks), then it is collapsed into Bvh's nodes.
struct BinaryNode {
    int left = -1, right = -1, item = -1, count = 0;
};

int build_binary(std::vector<BinaryNode>& nodes, std::vector<int>& items, int begin, int end,
                 const std::vector<Vec3>& centres) {
    const int index = static_cast<int>(nodes.size());
    nodes.emplace_back();
    nodes[index].count = end - begin;
    if (end - begin == 1) {
        nodes[index].item = items[begin];
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
    const int left = build_binary(nodes, items, begin, mid, centres);
    const int right = build_binary(nodes, items, mid, end, centres);
    nodes[index].left = left;
    nodes[index].right = right;
    return index;
}

// Leaves of a binary subtree in the order the first tree's queries visited them (right first).
void collect_ranks(const std::vector<BinaryNode>& nodes, int i, std::vector<int>& order) {
    if (nodes[i].item >= 0) {
        order.push_back(nodes[i].item);
        return;
    }
    collect_ranks(nodes, nodes[i].right, order);
    collect_ranks(nodes, nodes[i].left, order);
}

int collapse(const std::vector<BinaryNode>& binary, int i, std::vector<Bvh::Node>& nodes, std::vector<int>& order) {
    const int index = static_cast<int>(nodes.size());
    nodes.emplace_back();
    if (binary[i].count <= Bvh::kLeafSize) {
        nodes[index].begin = static_cast<int>(order.size());
        collect_ranks(binary, i, order);
        nodes[index].end = static_cast<int>(order.size());
        return index;
    }
    const int right = collapse(binary, binary[i].right, nodes, order);  // lower ranks
    const int left = collapse(binary, binary[i].left, nodes, order);
    nodes[index].left = left;
    nodes[index].right = right;
    nodes[index].begin = nodes[right].begin;
    nodes[index].end = nodes[left].end;
    return index;
}

}  // namespace

void Bvh::build(const std::vector<Aabb>& boxes, double margin) {
    nodes_.clear();
    order_.clear();
    rank_.clear();
    rank_boxes_.clear();
    margin_ = margin;
    if (boxes.empty()) return;
    std::vector<Vec3> centres(boxes.size());
    for (size_t i = 0; i < boxes.size(); ++i) {
        Aabb b = boxes[i];
        b.inflate(margin);
        centres[i] = 0.5 * (b.lo + b.hi);
    }
    std::vector<int> items(boxes.size());
    for (size_t i = 0; i < items.size(); ++i) items[i] = static_cast<int>(i);
    std::vector<BinaryNode> binary;
    binary.reserve(2 * boxes.size());
    build_binary(binary, items, 0, static_cast<int>(items.size()), centres);
    order_.reserve(boxes.size());
    collapse(binary, 0, nodes_, order_);
    rank_.assign(boxes.size(), -1);
    for (size_t r = 0; r < order_.size(); ++r) rank_[order_[r]] = static_cast<int>(r);
    rank_boxes_.resize(boxes.size());
    refit(boxes, margin);
}

void Bvh::refit(const std::vector<Aabb>& boxes, double margin) {
    for (size_t r = 0; r < order_.size(); ++r) rank_boxes_[r] = boxes[order_[r]];
    refit_nodes(margin);
}

void Bvh::refit_nodes(double margin) {
    margin_ = margin;
    // children always come after their parent, so a reverse sweep sees children first
    for (int i = static_cast<int>(nodes_.size()) - 1; i >= 0; --i) {
        Node& n = nodes_[i];
        if (n.leaf()) {
            Vec3 lo = rank_boxes_[n.begin].lo, hi = rank_boxes_[n.begin].hi;
            for (int r = n.begin + 1; r < n.end; ++r) {
                lo = lo.cwiseMin(rank_boxes_[r].lo);
                hi = hi.cwiseMax(rank_boxes_[r].hi);
            }
            n.lo = lo;
            n.hi = hi;
        } else {
            n.lo = nodes_[n.left].lo.cwiseMin(nodes_[n.right].lo);
            n.hi = nodes_[n.left].hi.cwiseMax(nodes_[n.right].hi);
        }
    }
}

Aabb Bvh::bounds() const {
    Aabb b;
    b.lo = nodes_.front().lo;
    b.hi = nodes_.front().hi;
    b.inflate(margin_);
    return b;
}

}  // namespace hh
