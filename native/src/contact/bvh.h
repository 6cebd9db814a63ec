// Broad phase: a bounding-volume hierarchy of axis-aligned boxes over a fixed set of items
// (surface triangles). Built once (median split), refitted every step as the surface moves.
//
// Items are numbered by rank: their order in a right-first depth-first walk of the binary
// median-split tree (the order in which the first, one-item-per-leaf version of this tree was
// queried). Detection breaks ties between equally close triangles by rank, so contacts do
// not depend on how the tree is traversed. Subtrees of up to kLeafSize items are collapsed
// into one leaf holding a contiguous range of ranks, which keeps the tree small. 8 rather than
// 4: the hand's self-collision descends along every pair of neighbouring patches down to the
// leaves (~16500 node pairs a frame with 4 on the 1695-tet hand, for ~2900 vertex-triangle
// tests), and fewer levels cost less than larger leaves (bench_detection.py compares two
// builds; the contacts are the same bit for bit).
//
// Boxes are stored tight (the items' own boxes) with one margin for all of them: an inflated
// box is computed as (lo - margin, hi + margin) when it is needed. Rounding is monotonic, so
// a node's inflated box is exactly the union of its items' inflated boxes, as if they had
// been inflated first.
#pragma once
#include <vector>

#include "contact/geometry.h"

namespace hh {

class Bvh {
public:
    static constexpr int kLeafSize = 8;
    struct Node {
        Vec3 lo, hi;          // tight: the union of its items' boxes, without the margin
        int left = -1, right = -1;
        int begin = 0, end = 0;  // the ranks of its items (a leaf when left < 0)
        bool leaf() const { return left < 0; }
    };

    // Topology from the centres of the item boxes inflated by margin (as they were when the
    // boxes were stored inflated), then a refit.
    void build(const std::vector<Aabb>& item_boxes, double margin = 0);
    void refit(const std::vector<Aabb>& item_boxes, double margin = 0);
    // The faster path for a caller that writes the tight item boxes in rank order itself
    // (rank_boxes()[rank_of(item)]) and then refits the nodes.
    std::vector<Aabb>& rank_boxes() { return rank_boxes_; }
    const std::vector<Aabb>& rank_boxes() const { return rank_boxes_; }
    void refit_nodes(double margin);
    // Refit with the tight box of the item of rank r given by box_of_rank(r), computed leaf by
    // leaf as the sweep reaches it: the boxes are written in order, never scattered.
    template <class BoxOfRank>
    void refit_ranks(double margin, BoxOfRank&& box_of_rank) {
        margin_ = margin;
        for (int i = static_cast<int>(nodes_.size()) - 1; i >= 0; --i) {
            Node& n = nodes_[i];
            if (n.leaf()) {
                Vec3 lo = Vec3::Constant(1e300), hi = Vec3::Constant(-1e300);
                for (int r = n.begin; r < n.end; ++r) {
                    const Aabb box = box_of_rank(r);
                    rank_boxes_[r] = box;
                    lo = lo.cwiseMin(box.lo);
                    hi = hi.cwiseMax(box.hi);
                }
                n.lo = lo;
                n.hi = hi;
            } else {
                n.lo = nodes_[n.left].lo.cwiseMin(nodes_[n.right].lo);
                n.hi = nodes_[n.left].hi.cwiseMax(nodes_[n.right].hi);
            }
        }
    }

    // Calls visit(item) for every item whose inflated box overlaps query, in rank order.
    template <class Visit>
    void query(const Aabb& query, Visit&& visit) const {
        query_ranks(query, [&](int r) { visit(order_[r]); });
    }
    template <class Visit>
    void query_ranks(const Aabb& query, Visit&& visit) const {
        if (nodes_.empty()) return;
        int stack[128];
        int top = 0;
        stack[top++] = 0;
        while (top > 0) {
            const Node& n = nodes_[stack[--top]];
            if (!overlaps_inflated(query.lo, query.hi, n.lo, n.hi)) continue;
            if (n.leaf()) {
                for (int r = n.begin; r < n.end; ++r)
                    if (overlaps_inflated(query.lo, query.hi, rank_boxes_[r].lo, rank_boxes_[r].hi)) visit(r);
            } else {
                // the right child first: ranks ascend
                stack[top++] = n.left;
                stack[top++] = n.right;
            }
        }
    }
    // Whether the box (lo, hi) overlaps (blo, bhi) inflated by the margin, as Aabb::overlaps
    // would on the inflated box (lower corner blo - margin, upper corner bhi + margin).
    bool overlaps_inflated(const Vec3& lo, const Vec3& hi, const Vec3& blo, const Vec3& bhi) const {
        return lo.x() <= bhi.x() + margin_ && lo.y() <= bhi.y() + margin_ && lo.z() <= bhi.z() + margin_ &&
               blo.x() - margin_ <= hi.x() && blo.y() - margin_ <= hi.y() && blo.z() - margin_ <= hi.z();
    }
    bool point_in_inflated(const Vec3& p, const Vec3& blo, const Vec3& bhi) const { return overlaps_inflated(p, p, blo, bhi); }
    // The same with the margin grown by `extra` (a query that reaches further, see detect_pair).
    bool overlaps_inflated(const Vec3& lo, const Vec3& hi, const Vec3& blo, const Vec3& bhi, double extra) const {
        const double m = margin_ + extra;
        return lo.x() <= bhi.x() + m && lo.y() <= bhi.y() + m && lo.z() <= bhi.z() + m && blo.x() - m <= hi.x() &&
               blo.y() - m <= hi.y() && blo.z() - m <= hi.z();
    }

    Aabb bounds() const;  // the root's inflated box
    bool empty() const { return nodes_.empty(); }
    double margin() const { return margin_; }
    const std::vector<Node>& nodes() const { return nodes_; }
    const std::vector<int>& order() const { return order_; }  // rank -> item
    int rank_of(int item) const { return rank_[item]; }
    int n_items() const { return static_cast<int>(order_.size()); }

private:
    std::vector<Node> nodes_;        // parents before children; node 0 is the root
    std::vector<int> order_, rank_;  // rank -> item, item -> rank
    std::vector<Aabb> rank_boxes_;   // tight item boxes by rank
    double margin_ = 0;
};

}  // namespace hh
