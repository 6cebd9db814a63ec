#include "solver/block_ldlt.h"
#include "solver/panel_kernels.h"

// The SIMD helpers return vector values from always-inline functions that are only ever
// inlined into kernels compiled for AVX2 / AVX-512; GCC still warns about the ABI.
#pragma GCC diagnostic ignored "-Wpsabi"

#include <Eigen/OrderingMethods>
#include <algorithm>
#include <cstdlib>
#include <numeric>
#include <type_traits>

namespace hh {

void BlockLDLT::analyze(const SpMat& a) {
    n_ = static_cast<int>(a.cols() / 3);
    const int* outer = a.outerIndexPtr();
    const int* inner = a.innerIndexPtr();
    auto offset = [&](int row, int col) {
        const int* begin = inner + outer[col];
        const int* end = inner + outer[col + 1];
        const int* it = std::lower_bound(begin, end, row);
        if (it == end || *it != row) throw std::logic_error("BlockLDLT: pattern is not made of 3x3 blocks");
        return static_cast<int>(it - inner);
    };
    // node graph: block (i, k) present when scalar (3i, 3k) is
    std::vector<Eigen::Triplet<double>> trip;
    for (int k = 0; k < n_; ++k)
        for (int p = outer[3 * k]; p < outer[3 * k + 1]; ++p)
            if (inner[p] % 3 == 0) trip.emplace_back(inner[p] / 3, k, 1.0);
    SpMat graph(n_, n_);
    graph.setFromTriplets(trip.begin(), trip.end());
    Eigen::PermutationMatrix<Eigen::Dynamic, Eigen::Dynamic, int> perm;
    Eigen::AMDOrdering<int> amd;
    amd(graph, perm);  // eliminate old node perm.indices()[new] at step new
    order_.assign(perm.indices().data(), perm.indices().data() + n_);
    inverse_.assign(n_, 0);
    for (int k = 0; k < n_; ++k) inverse_[order_[k]] = k;

    column_.assign(n_, {});
    for (int k = 0; k < n_; ++k) {
        const int old_k = order_[k];
        for (SpMat::InnerIterator it(graph, old_k); it; ++it) {
            const int old_i = static_cast<int>(it.row());
            const int i = inverse_[old_i];
            if (i > k) continue;
            BlockRef ref;
            ref.row = i;
            for (int r = 0; r < 3; ++r)
                for (int c = 0; c < 3; ++c) ref.offsets[3 * r + c] = offset(3 * old_i + r, 3 * old_k + c);
            column_[k].push_back(ref);
        }
    }
    lower_.assign(n_, {});
    for (int k = 0; k < n_; ++k) {
        const int old_k = order_[k];
        for (SpMat::InnerIterator it(graph, old_k); it; ++it) {
            const int old_i = static_cast<int>(it.row());
            const int i = inverse_[old_i];
            if (i < k) continue;
            BlockRef ref;
            ref.row = i;
            for (int r = 0; r < 3; ++r)
                for (int c = 0; c < 3; ++c) ref.offsets[3 * r + c] = offset(3 * old_i + r, 3 * old_k + c);
            lower_[k].push_back(ref);
        }
        std::sort(lower_[k].begin(), lower_[k].end(), [](const BlockRef& a, const BlockRef& b) { return a.row < b.row; });
    }
    // elimination tree and column counts of L (Davis, LDL symbolic)
    parent_.assign(n_, -1);
    lnz_.assign(n_, 0);
    flag_.assign(n_, -1);
    for (int k = 0; k < n_; ++k) {
        flag_[k] = k;
        for (const BlockRef& ref : column_[k])
            for (int i = ref.row; i < k && flag_[i] != k; i = parent_[i]) {
                if (parent_[i] == -1) parent_[i] = k;
                ++lnz_[i];
                flag_[i] = k;
            }
    }
    factor_flops_ = 0;
    for (int k = 0; k < n_; ++k) factor_flops_ += 54.0 * lnz_[k] * (lnz_[k] + 1) / 2 + 54.0 * lnz_[k];
    lp_.assign(n_ + 1, 0);
    for (int k = 0; k < n_; ++k) lp_[k + 1] = lp_[k] + lnz_[k];
    li_.assign(lp_[n_], 0);
    lx_.assign(lp_[n_], Mat3::Zero());
    d_inverse_.assign(n_, Mat3::Identity());
    y_.assign(n_, Mat3::Zero());
    pattern_.assign(n_, 0);
    factored_ = single_valid_ = false;
    if (supernodal_) analyze_supernodes();
}

void BlockLDLT::analyze_supernodes() {
    // column structures of L (rows below the diagonal, ascending), from the elimination tree
    std::vector<int> cp(n_ + 1, 0), fill(n_, 0);
    for (int k = 0; k < n_; ++k) cp[k + 1] = cp[k] + lnz_[k];
    std::vector<int> rows(cp[n_]);
    std::fill(flag_.begin(), flag_.end(), -1);
    for (int k = 0; k < n_; ++k) {
        flag_[k] = k;
        for (const BlockRef& ref : column_[k])
            for (int i = ref.row; i < k && flag_[i] != k; i = parent_[i]) {
                rows[cp[i] + fill[i]++] = k;
                flag_[i] = k;
            }
    }
    // fundamental supernodes: k joins k-1's when k is its parent and their structures match
    std::vector<int> first;  // of each fundamental supernode
    for (int k = 0; k < n_; ++k)
        if (k == 0 || !(parent_[k - 1] == k && lnz_[k - 1] == lnz_[k] + 1)) first.push_back(k);
    // Relaxed amalgamation (as CHOLMOD's, Ashcraft & Grimes 1989): a supernode joins its parent
    // when it ends just before it (the parent's last child in the postorder AMD gives) and the
    // explicit zeros that adds stay few for the size. In the fundamental form the 17208-tet
    // hand's 4141 nodes made 2203 supernodes of ~2 nodes: dense kernels on 6-column panels and
    // the scatter of their updates, ~11 Gflop/s.
    {
        const int nf = static_cast<int>(first.size());
        std::vector<int> last(nf), cols(nf), below(nf), sn_of(n_);
        std::vector<double> nonzero(nf);  // L's nonzero node blocks in each (merged) supernode
        for (int f = 0; f < nf; ++f) {
            const int end = f + 1 < nf ? first[f + 1] : n_;
            last[f] = end - 1;
            cols[f] = end - first[f];
            below[f] = lnz_[end - 1];
            for (int k = first[f]; k < end; ++k) sn_of[k] = f;
            nonzero[f] = 0.5 * cols[f] * (cols[f] + 1) + double(cols[f]) * below[f];  // (none zero yet)
        }
        std::vector<char> absorbed(nf, 0);
        for (int f = 0; f < nf; ++f) {
            const int pnode = parent_[last[f]];
            if (pnode < 0) continue;
            const int q = sn_of[pnode];
            if (first[q] != last[f] + 1) continue;  // not adjacent: its nodes would not be consecutive
            const int c = cols[f] + cols[q];  // nodes of the merged supernode
            const double all = 0.5 * c * (c + 1) + double(c) * below[q];
            const double zeros = all - nonzero[f] - nonzero[q];
            const double z = zeros / all;
            const int scalar_cols = 3 * c;
            const bool merge = scalar_cols <= 4 || (scalar_cols <= 16 && z < 0.8) || (scalar_cols <= 48 && z < 0.1) || z < 0.05;
            if (!merge) continue;
            absorbed[f] = 1;
            first[q] = first[f];
            cols[q] = c;
            nonzero[q] += nonzero[f];
        }
        std::vector<int> kept;
        for (int f = 0; f < nf; ++f)
            if (!absorbed[f]) kept.push_back(first[f]);
        first = std::move(kept);
    }
    sn_start_ = first;
    sn_start_.push_back(n_);
    node_sn_.assign(n_, 0);
    for (int s = 0; s + 1 < static_cast<int>(sn_start_.size()); ++s)
        for (int k = sn_start_[s]; k < sn_start_[s + 1]; ++k) node_sn_[k] = s;
    const int ns = static_cast<int>(sn_start_.size()) - 1;
    sn_rows_ptr_.assign(ns + 1, 0);
    sn_val_ptr_.assign(ns + 1, 0);
    sn_rows_.clear();
    for (int s = 0; s < ns; ++s) {
        const int c0 = sn_start_[s], c1 = sn_start_[s + 1], last = c1 - 1;
        for (int c = c0; c < c1; ++c) sn_rows_.push_back(c);
        sn_rows_.insert(sn_rows_.end(), rows.begin() + cp[last], rows.begin() + cp[last + 1]);
        sn_rows_ptr_[s + 1] = static_cast<int>(sn_rows_.size());
        const size_t nr = sn_rows_ptr_[s + 1] - sn_rows_ptr_[s];
        sn_val_ptr_[s + 1] = sn_val_ptr_[s] + 9 * nr * (c1 - c0);
    }
    sn_val_.assign(sn_val_ptr_[ns], 0.0);
    sn_diag_ptr_.assign(ns + 1, 0);
    for (int s = 0; s < ns; ++s) sn_diag_ptr_[s + 1] = sn_diag_ptr_[s] + 3 * (sn_start_[s + 1] - sn_start_[s]);
    sn_diag_inverse_.assign(sn_diag_ptr_[ns], 0.0);
    // the copies' storage as well (make_single fills it): allocated and touched here, with the
    // factor's, rather than in the first factorization, whose step it made ~5 ms longer on the
    // grasping hand (~3.6 MB of copies, freshly mapped pages)
    if (keep_single_ || keep_half_) sn_val_single_.assign(sn_val_.size(), 0.0f);
    if (keep_half_ && has_f16c()) {
        sn_val_half_.assign(sn_val_.size(), Half());
        sn_scale_.assign(sn_diag_inverse_.size(), 0.0f);
    }
    for (PartWork& w : part_work_) w.relmap.assign(n_, 0);
    discard_parts();
    link_head_.assign(ns, -1);
    link_next_.assign(ns, -1);
    sn_pos_.assign(ns, 0);
    split_supernodes();
    // the up-looking form's arrays are not needed
    lx_.clear();
    lx_.shrink_to_fit();
    li_.assign(cp[n_], 0);
}

void BlockLDLT::factorize(const SpMat& a, const Beside& beside) {
    factored_ = false;
    if (supernodal_) {
        factorize_supernodal(a, beside);
        factored_ = true;
        single_valid_ = half_valid_ = false;
        if (keep_single_ || keep_half_) make_single(beside);  // (in two shares with `beside`)
        return;
    }
    factorize_up_looking(a);
}

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && __GNUC__ >= 12 && !defined(__SANITIZE_THREAD__)
__attribute__((target_clones("arch=x86-64-v3", "default")))
#endif
void BlockLDLT::factorize_up_looking(const SpMat& a) {
    const double* values = a.valuePtr();
    std::fill(flag_.begin(), flag_.end(), -1);
    std::fill(lnz_.begin(), lnz_.end(), 0);
    for (int k = 0; k < n_; ++k) {
        // scatter column k of the permuted A (upper part) into y, and find the pattern of
        // row k of L by walking up the elimination tree
        y_[k].setZero();
        int top = n_;
        flag_[k] = k;
        for (const BlockRef& ref : column_[k]) {
            Mat3& yi = y_[ref.row];
            for (int e = 0; e < 9; ++e) yi(e / 3, e % 3) += values[ref.offsets[e]];
            int len = 0;
            for (int i = ref.row; flag_[i] != k; i = parent_[i]) {
                pattern_[len++] = i;
                flag_[i] = k;
            }
            while (len > 0) pattern_[--top] = pattern_[--len];
        }
        Mat3 dk = y_[k];
        y_[k].setZero();
        for (; top < n_; ++top) {
            const int i = pattern_[top];
            const Mat3 yi = y_[i];
            y_[i].setZero();
            const int end = lp_[i] + lnz_[i];
            for (int p = lp_[i]; p < end; ++p) y_[li_[p]].noalias() -= lx_[p] * yi;
            const Mat3 lki = yi.transpose() * d_inverse_[i];  // L(k, i) = Y_i^T D_i^-1
            dk.noalias() -= lki * yi;
            li_[end] = k;
            lx_[end] = lki;
            ++lnz_[i];
        }
        const Mat3 dsym = 0.5 * (dk + dk.transpose());
        Eigen::LLT<Mat3> llt(dsym);
        if (llt.info() != Eigen::Success || !dsym.allFinite())
            throw NumericalError(
                "the deformable system At is not positive definite (block LDL^T failed): check for "
                "inverted elements, negative parameters or a far too large time step");
        const Mat3 dinv = llt.solve(Mat3::Identity());
        d_inverse_[k] = 0.5 * (dinv + dinv.transpose());  // exactly symmetric, so L D L^T is
    }
    factored_ = true;
    single_valid_ = half_valid_ = false;
    if (keep_single_) make_single();
}

void BlockLDLT::factorize_part(const SpMat& a, int part) {
    if (!supernodal_ || factor_parts_ == 0 || part < 0 || part > 1) throw std::logic_error("BlockLDLT::factorize_part: no such part");
    const int ns = supernodes();
    for (int j = 0; j < ns; ++j)
        if (sn_part_[j] == part) link_head_[j] = -1;
    part_work_[part].pending.clear();
    for (int j = 0; j < ns; ++j)
        if (sn_part_[j] == part) factor_supernode(a.valuePtr(), j, part, nullptr);
    part_done_[part] = true;
}

void BlockLDLT::factorize_supernodal(const SpMat& a, const Beside& beside) {
    const int ns = supernodes();
    for (int part = 0; part < factor_parts_; ++part)
        if (!part_done_[part]) factorize_part(a, part);
    discard_parts();
    for (int j = 0; j < ns; ++j)
        if (sn_part_[j] == 2) link_head_[j] = -1;
    // the parts' supernodes whose next rows are in the rest, in a fixed order
    for (int part = 0; part < factor_parts_; ++part)
        for (int k : part_work_[part].pending) {
            const int target = node_sn_[sn_rows_[sn_rows_ptr_[k] + sn_pos_[k]]];
            link_next_[k] = link_head_[target];
            link_head_[target] = k;
        }
    for (int j = 0; j < ns; ++j)
        if (sn_part_[j] == 2) factor_supernode(a.valuePtr(), j, 2, &beside);
}

// Supernode j: A's columns, the updates of the descendants queued for it, its panel's Cholesky,
// then queued for its own next target (in its part, or pending for the rest).
void BlockLDLT::factor_supernode(const double* values, int j, int part, const Beside* beside) {
    PartWork& work = part_work_[part == 2 ? 0 : part];
    std::vector<int>& relmap = work.relmap;
    auto link = [&](int k) {  // queue supernode k for the supernode owning its next row
        const int target = node_sn_[sn_rows_[sn_rows_ptr_[k] + sn_pos_[k]]];
        if (sn_part_[target] != part) {
            work.pending.push_back(k);
            return;
        }
        link_next_[k] = link_head_[target];
        link_head_[target] = k;
    };
    const int c0 = sn_start_[j], c1 = sn_start_[j + 1], width = c1 - c0, m = 3 * width;
    const int* rows = sn_rows_.data() + sn_rows_ptr_[j];
    const int nr = sn_rows_ptr_[j + 1] - sn_rows_ptr_[j], ld = 3 * nr;
    double* p = sn_val_.data() + sn_val_ptr_[j];
    std::fill(p, p + static_cast<size_t>(ld) * m, 0.0);
    for (int t = 0; t < nr; ++t) relmap[rows[t]] = t;
    for (int c = c0; c < c1; ++c)  // A's columns of the supernode, lower part
        for (const BlockRef& ref : lower_[c]) {
            double* to = p + static_cast<size_t>(3 * (c - c0)) * ld + 3 * relmap[ref.row];
            for (int r = 0; r < 3; ++r)
                for (int q = 0; q < 3; ++q) to[static_cast<size_t>(q) * ld + r] = values[ref.offsets[3 * r + q]];
        }
    // updates from the descendants whose next rows fall in this supernode's columns, in the
    // order they were queued; the panel's columns [0, split) and [split, m) as two shares (each
    // its own update buffer; they write disjoint columns), side by side when `beside` runs them
    // so. Each entry of the panel loses the same products in the same order either way.
    std::vector<int>& descendants = work.descendants;
    descendants.clear();
    for (int k = link_head_[j]; k != -1; k = link_next_[k]) descendants.push_back(k);
    auto share = [&](int from_column, int to_column, std::vector<double>& update) {
        for (const int k : descendants) {
            const int* krows = sn_rows_.data() + sn_rows_ptr_[k];
            const int knr = sn_rows_ptr_[k + 1] - sn_rows_ptr_[k], kld = 3 * knr;
            const int km = 3 * (sn_start_[k + 1] - sn_start_[k]);
            const int first = sn_pos_[k];
            const int q = knr - first;
            // its rows [a, b) among those in this supernode's columns fall in the share's columns
            int a = 0;
            while (first + a < knr && krows[first + a] < c0 + from_column / 3) ++a;
            int b = a;
            while (first + b < knr && krows[first + b] < c0 + to_column / 3) ++b;
            if (b == a) continue;
            // U = Lq Lq(rows a..b)^T from row a down: the dense update, the bulk of the
            // factorization's flops
            const int rows = 3 * (q - a), columns = 3 * (b - a);
            const double* lq = sn_val_.data() + sn_val_ptr_[k] + 3 * (first + a);
            update.resize(static_cast<size_t>(rows) * columns);
            panel_outer_product(lq, kld, rows, columns, km, update.data());
            for (int cc = 0; cc < columns; ++cc) {  // (its lower part: the panel's upper one is never read)
                const int t0 = a + cc / 3;
                double* to = p + static_cast<size_t>(3 * (krows[first + t0] - c0) + cc % 3) * ld;
                const double* from = update.data() + static_cast<size_t>(cc) * rows - 3 * static_cast<size_t>(a);
                for (int t = t0; t < q; ++t) {
                    double* dst = to + 3 * relmap[krows[first + t]];
                    dst[0] -= from[3 * t];
                    dst[1] -= from[3 * t + 1];
                    dst[2] -= from[3 * t + 2];
                }
            }
        }
    };
    const int split = part == 2 ? sn_split_[j] : 0;
    if (split > 0) {
        std::vector<double>& other = part_work_[1].update;
        if (beside && *beside) (*beside)([&] { share(0, split, work.update); }, [&] { share(split, m, other); });
        else {
            share(0, split, work.update);
            share(split, m, other);
        }
    } else {
        share(0, m, work.update);
    }
    for (const int k : descendants) {  // each one on to its next target
        const int* krows = sn_rows_.data() + sn_rows_ptr_[k];
        const int knr = sn_rows_ptr_[k + 1] - sn_rows_ptr_[k];
        int first = sn_pos_[k];
        while (first < knr && krows[first] < c1) ++first;
        sn_pos_[k] = first;
        if (first < knr) link(k);
    }
    if (!panel_cholesky(p, ld, m))
        throw NumericalError(
            "the deformable system At is not positive definite (block LDL^T failed): check for "
            "inverted elements, negative parameters or a far too large time step");
    for (int c = 0; c < m; ++c) sn_diag_inverse_[sn_diag_ptr_[j] + c] = 1.0 / p[static_cast<size_t>(c) * ld + c];
    if (nr > width) {
        sn_pos_[j] = width;
        link(j);
    }
}

// The two parts: whole subtrees of the supernodal elimination tree in two sets of about equal
// estimated work, the rest (their ancestors) after them. Each supernode's work counts its
// panel's Cholesky and the updates it receives (it computes them when it is factored), so the
// rest carries the updates the parts send up. Starting from the roots, the heaviest subtree is
// opened (its root goes to the rest, its children become subtrees) while that lowers the
// estimated time on two threads, max(part 0, part 1) + rest; the subtrees are dealt out
// heaviest first to the lighter set.
void BlockLDLT::split_supernodes() {
    const int ns = supernodes();
    sn_part_.assign(ns, 2);
    sn_split_.assign(ns, 0);
    factor_parts_ = 0;
    std::vector<double> work(ns, 0.0), subtree(ns, 0.0);
    std::vector<int> sn_parent(ns, -1);
    for (int k = 0; k < ns; ++k) {
        const int w = 3 * (sn_start_[k + 1] - sn_start_[k]);
        const int nr = sn_rows_ptr_[k + 1] - sn_rows_ptr_[k];
        const int below = 3 * nr - w;
        work[k] += w * double(w) * w / 3 + double(below) * w * w;
        const int* krows = sn_rows_.data() + sn_rows_ptr_[k];
        const int own = sn_start_[k + 1] - sn_start_[k];
        if (own < nr) sn_parent[k] = node_sn_[krows[own]];
        for (int t = own; t < nr;) {  // its updates, per target supernode
            const int target = node_sn_[krows[t]];
            int q1 = 0;
            while (t + q1 < nr && node_sn_[krows[t + q1]] == target) ++q1;
            const double q = 3.0 * (nr - t);
            work[target] += q * 3.0 * q1 * w;
            t += q1;
        }
    }
    double total = 0;
    for (int k = 0; k < ns; ++k) {
        subtree[k] += work[k];
        if (sn_parent[k] >= 0) subtree[sn_parent[k]] += subtree[k];
        total += work[k];
    }
    // below ~2e7 estimated flops a part costs more to schedule than it saves
    if (total < 2e7) return;
    std::vector<std::vector<int>> children(ns);
    std::vector<int> candidates;
    for (int k = 0; k < ns; ++k) {
        if (sn_parent[k] >= 0) children[sn_parent[k]].push_back(k);
        else candidates.push_back(k);
    }
    double rest = 0, best = total;
    std::vector<std::pair<int, int>> best_sets;  // (subtree root, part)
    for (int round = 0; round < 256 && !candidates.empty(); ++round) {
        std::sort(candidates.begin(), candidates.end(), [&](int x, int y) { return subtree[x] > subtree[y] || (subtree[x] == subtree[y] && x < y); });
        double bins[2] = {0, 0};
        std::vector<std::pair<int, int>> sets;
        for (int c : candidates) {
            const int bin = bins[1] < bins[0] ? 1 : 0;
            bins[bin] += subtree[c];
            sets.emplace_back(c, bin);
        }
        const double cost = std::max(bins[0], bins[1]) + rest;
        if (cost < best && bins[0] > 0 && bins[1] > 0) {
            best = cost;
            best_sets = sets;
        }
        const int open = candidates.front();  // the heaviest subtree
        candidates.erase(candidates.begin());
        rest += work[open];
        candidates.insert(candidates.end(), children[open].begin(), children[open].end());
    }
    if (best > 0.9 * total || best_sets.empty()) return;  // not worth two parts
    std::vector<int> root_part(ns, -1);
    for (const auto& e : best_sets) root_part[e.first] = e.second;
    for (int k = ns - 1; k >= 0; --k) {  // (a parent after its children: top down here)
        if (root_part[k] >= 0) sn_part_[k] = static_cast<unsigned char>(root_part[k]);
        else if (sn_parent[k] >= 0 && sn_part_[sn_parent[k]] != 2) sn_part_[k] = sn_part_[sn_parent[k]];
    }
    factor_parts_ = 2;
    // The rest's large supernodes take their descendants' updates in two shares of their
    // columns (factor_supernode), split where the estimated flops of the updates even out. The
    // rest ran alone on one thread: ~13 of the ~25 ms of the ~17000-tet hand's factorization,
    // two thirds of it these updates.
    std::vector<double> node_work(n_, 0.0);  // per node of the rest: the update flops its columns receive
    for (int k = 0; k < ns; ++k) {
        const int w = 3 * (sn_start_[k + 1] - sn_start_[k]);
        const int* krows = sn_rows_.data() + sn_rows_ptr_[k];
        const int own = sn_start_[k + 1] - sn_start_[k], nr = sn_rows_ptr_[k + 1] - sn_rows_ptr_[k];
        for (int t = own; t < nr; ++t)
            if (sn_part_[node_sn_[krows[t]]] == 2) node_work[krows[t]] += 3.0 * (nr - t) * 3.0 * w;
    }
    for (int j = 0; j < ns; ++j) {
        if (sn_part_[j] != 2) continue;
        double total = 0;
        for (int i = sn_start_[j]; i < sn_start_[j + 1]; ++i) total += node_work[i];
        if (total < kSplitUpdateFlops) continue;
        double sum = 0;
        int i = sn_start_[j];
        while (i < sn_start_[j + 1] && sum + node_work[i] <= 0.5 * total) sum += node_work[i++];
        if (i > sn_start_[j] && i < sn_start_[j + 1]) sn_split_[j] = 3 * (i - sn_start_[j]);
    }
}

void BlockLDLT::make_single(const Beside& beside) {
    if (supernodal_) {
        const bool single = keep_single_ || keep_half_;  // (the half kernels' fallback)
        const bool half = keep_half_ && has_f16c();
        if (single) sn_val_single_.resize(sn_val_.size());
        if (half) {
            sn_val_half_.resize(sn_val_.size());
            sn_scale_.resize(sn_diag_inverse_.size());
        }
        // supernodes [from, to): each copy's entries of those supernodes only, column by column,
        // both copies while the column is in the cache and its largest magnitude found in
        // vector registers (on the grasping hand's factor ~1 ms of a renewal, against ~1.8 ms
        // in two passes over the factor with a scalar search)
        auto copies = [&](int from, int to) {
            for (int j = from; j < to; ++j) {
                const int m = 3 * (sn_start_[j + 1] - sn_start_[j]);
                const size_t ld = 3 * static_cast<size_t>(sn_rows_ptr_[j + 1] - sn_rows_ptr_[j]);
                for (int c = 0; c < m; ++c) {
                    const size_t at = sn_val_ptr_[j] + c * ld;
                    const Eigen::Map<const Eigen::VectorXd> column(sn_val_.data() + at, static_cast<Eigen::Index>(ld));
                    if (single) Eigen::Map<Eigen::VectorXf>(sn_val_single_.data() + at, column.size()) = column.cast<float>();
                    if (!half) continue;
                    // each scalar column over its largest magnitude (a float scale: the products
                    // with it are the kernels' only use of it)
                    const double largest = column.cwiseAbs().maxCoeff();
                    const float scale = largest > 0 ? static_cast<float>(largest) : 1.0f;
                    sn_scale_[sn_diag_ptr_[j] + c] = scale;
                    to_half(column.data(), ld, scale, sn_val_half_.data() + at);
                }
            }
        };
        // Two shares of about equal values, side by side when `beside` runs them so (each
        // entry is converted on its own: the same copies either way). On one thread the copies
        // of the ~17000-tet hand's factor took ~2.2 ms of each renewal, the other thread idle.
        const int ns = supernodes();
        int middle = 0;
        while (middle < ns && 2 * sn_val_ptr_[middle + 1] <= sn_val_ptr_[ns]) ++middle;
        if (beside) beside([&] { copies(0, middle); }, [&] { copies(middle, ns); });
        else copies(0, ns);
        single_valid_ = single;
        half_valid_ = half;
        return;
    }
    lx_single_.resize(9 * lx_.size());
    d_inverse_single_.resize(9 * static_cast<size_t>(n_));
    for (int k = 0; k < n_; ++k) {  // only the first lnz_[k] entries of each column are L's
        const Mat3* from = lx_.data() + lp_[k];
        float* to = lx_single_.data() + 9 * static_cast<size_t>(lp_[k]);
        for (int p = 0; p < lnz_[k]; ++p)
            for (int e = 0; e < 9; ++e) to[9 * p + e] = static_cast<float>(from[p].data()[e]);
        for (int e = 0; e < 9; ++e) d_inverse_single_[9 * static_cast<size_t>(k) + e] = static_cast<float>(d_inverse_[k].data()[e]);
    }
    single_valid_ = true;
}

namespace {

// L D L^T x = b on the permuted right-hand sides, K at a time, stored node-major so that a
// node's 3 x K values are contiguous: every 3x3 block of L is loaded once for all K. The
// factor's values are LT (double, or float for the single-precision copy); the arithmetic is
// always double, so a float factor is an exact linear operator (L_f D_f L_f^T) and CG stays CG.
template <typename LT>
struct Factor {
    int n;
    const int *lp, *lnz, *li;
    const LT *lx, *d_inverse;  // 3x3 blocks, column-major, 9 values each
    // Null, or per permuted node: whether its values are wanted. Closed under elimination-tree
    // ancestors, so the backward pass can skip the rest (see BlockLDLT::solve).
    const unsigned char* wanted;
    const unsigned char* path = nullptr;  // null, or per permuted node: the forward pass visits only these
};

// Four and eight doubles as one value (GCC/Clang vector extension): explicit SIMD the compiler
// maps to AVX / AVX-512 registers; aligned(8) allows unaligned loads and stores.
// (Template arguments drop type attributes such as aligned(8), so the kernels take the lane
// count L and name the type through Lanes<L>::V.)
typedef double V4 __attribute__((vector_size(32), aligned(8)));
typedef double V8 __attribute__((vector_size(64), aligned(8)));
template <int L> struct Lanes;
template <> struct Lanes<1> { typedef double V; };
template <> struct Lanes<4> { typedef V4 V; };
template <> struct Lanes<8> { typedef V8 V; };

// V: the SIMD value of L lanes (double for one right-hand side, V4 or V8), N of them per row of a node's
// 3 x K block (K = N * lanes of V).
template <int L, int N, typename LT>
__attribute__((always_inline)) inline void solve_permuted(const Factor<LT>& f, double* x) {
    typedef typename Lanes<L>::V V;
    V* xv = reinterpret_cast<V*>(x);
    for (int i = 0; i < f.n; ++i) {  // L z = b
        // A node whose values are all still zero adds nothing below it: skipped. With sparse
        // right-hand sides (the contact responses' unit columns) only the elimination-tree
        // paths above their nodes are touched; a dense one leaves at its first value. With
        // `path` (unit columns) only its nodes are nonzero: no scan.
        if (f.path) {
            if (!f.path[i]) continue;
        } else {
            const double* xs = x + static_cast<size_t>(3 * N * L) * i;
            int e0 = 0;
            while (e0 < 3 * N * L && xs[e0] == 0) ++e0;
            if (e0 == 3 * N * L) continue;
        }
        V xi[3 * N];
        for (int e = 0; e < 3 * N; ++e) xi[e] = xv[3 * N * i + e];
        for (int p = f.lp[i], end = f.lp[i] + f.lnz[i]; p < end; ++p) {
            const LT* l = f.lx + 9 * p;
            V* xr = xv + 3 * N * f.li[p];
            for (int r = 0; r < 3; ++r) {
                const double l0 = l[r], l1 = l[3 + r], l2 = l[6 + r];
                for (int j = 0; j < N; ++j) xr[r * N + j] -= l0 * xi[j] + l1 * xi[N + j] + l2 * xi[2 * N + j];
            }
        }
    }
    for (int i = 0; i < f.n; ++i) {  // z <- D^-1 z
        if (f.wanted && !f.wanted[i]) continue;
        V* xi = xv + 3 * N * i;
        const LT* d = f.d_inverse + 9 * i;
        V t[3 * N];
        for (int r = 0; r < 3; ++r) {
            const double d0 = d[r], d1 = d[3 + r], d2 = d[6 + r];
            for (int j = 0; j < N; ++j) t[r * N + j] = d0 * xi[j] + d1 * xi[N + j] + d2 * xi[2 * N + j];
        }
        for (int e = 0; e < 3 * N; ++e) xi[e] = t[e];
    }
    for (int i = f.n - 1; i >= 0; --i) {  // L^T x = z
        // x_i needs x only at i's elimination-tree ancestors (L(r, i) != 0 means r is one), so
        // for a set of wanted nodes closed under ancestors the others can be left out.
        if (f.wanted && !f.wanted[i]) continue;
        V t[3 * N];
        V* xi = xv + 3 * N * i;
        for (int e = 0; e < 3 * N; ++e) t[e] = xi[e];
        for (int p = f.lp[i], end = f.lp[i] + f.lnz[i]; p < end; ++p) {
            const LT* l = f.lx + 9 * p;
            const V* xr = xv + 3 * N * f.li[p];
            for (int c = 0; c < 3; ++c) {
                const double l0 = l[3 * c], l1 = l[3 * c + 1], l2 = l[3 * c + 2];
                for (int j = 0; j < N; ++j) t[c * N + j] -= l0 * xr[j] + l1 * xr[N + j] + l2 * xr[2 * N + j];
            }
        }
        for (int e = 0; e < 3 * N; ++e) xi[e] = t[e];
    }
}

// y = A x on node-major storage for a symmetric A whose pattern is made of 3x3 node blocks
// (the three columns of a node share their row pattern): column 3j + c of the compressed-
// column storage is row 3j + c. One index per block, each x row loaded once for 3 outputs.
template <int L, int N>
__attribute__((always_inline)) inline void multiply_blocks(int n, const int* outer, const int* inner, const double* values,
                                                           const double* x, double* y) {
    typedef typename Lanes<L>::V V;
    const V* xv = reinterpret_cast<const V*>(x);
    V* yv = reinterpret_cast<V*>(y);
    for (int j = 0; j < n; ++j) {
        const int o0 = outer[3 * j], o1 = outer[3 * j + 1], o2 = outer[3 * j + 2];
        const int blocks = (o1 - o0) / 3;
        V acc[3 * N] = {};
        for (int k = 0; k < blocks; ++k) {
            const V* xi = xv + N * inner[o0 + 3 * k];  // row 3i: its 3 x K block
            const double* v0 = values + o0 + 3 * k;
            const double* v1 = values + o1 + 3 * k;
            const double* v2 = values + o2 + 3 * k;
            for (int q = 0; q < N; ++q) {
                const V a = xi[q], b = xi[N + q], c = xi[2 * N + q];
                acc[q] += v0[0] * a + v0[1] * b + v0[2] * c;
                acc[N + q] += v1[0] * a + v1[1] * b + v1[2] * c;
                acc[2 * N + q] += v2[0] * a + v2[1] * b + v2[2] * c;
            }
        }
        for (int e = 0; e < 3 * N; ++e) yv[3 * N * j + e] = acc[e];
    }
}

// The same loops compiled for AVX2 + FMA and for AVX-512, chosen at run time when the CPU has
// them: the library itself is built for the baseline x86-64 instruction set.
#if defined(__GNUC__) && defined(__x86_64__)
#define HH_HAVE_SIMD_KERNELS 1
template <int L, int N, typename LT>
__attribute__((target("avx2,fma"))) void solve_avx2(const Factor<LT>& f, double* x) {
    solve_permuted<L, N, LT>(f, x);
}
template <int L, int N, typename LT>
__attribute__((target("avx512f,avx512vl,avx2,fma"))) void solve_avx512(const Factor<LT>& f, double* x) {
    solve_permuted<L, N, LT>(f, x);
}
template <int L, int N>
__attribute__((target("avx2,fma"))) void multiply_avx2(int n, const int* o, const int* i, const double* v, const double* x, double* y) {
    multiply_blocks<L, N>(n, o, i, v, x, y);
}
template <int L, int N>
__attribute__((target("avx512f,avx512vl,avx2,fma"))) void multiply_avx512(int n, const int* o, const int* i, const double* v,
                                                                         const double* x, double* y) {
    multiply_blocks<L, N>(n, o, i, v, x, y);
}
int simd_level() { return active_simd_level(); }  // 0: baseline, 1: AVX2 + FMA, 2: AVX-512
#endif

}  // namespace

namespace {

template <typename LT>
void solve_dispatch(const Factor<LT>& f, double* x, int w) {
#ifdef HH_HAVE_SIMD_KERNELS
    const int level = simd_level();
    if (level == 2) {
        if (w == 1) return solve_avx512<1, 1, LT>(f, x);
        if (w == 4) return solve_avx512<4, 1, LT>(f, x);
        if (w == 16) return solve_avx512<8, 2, LT>(f, x);
        return solve_avx512<8, 1, LT>(f, x);
    }
    if (level == 1) {
        if (w == 1) return solve_avx2<1, 1, LT>(f, x);
        if (w == 4) return solve_avx2<4, 1, LT>(f, x);
        if (w == 16) return solve_avx2<4, 4, LT>(f, x);
        return solve_avx2<4, 2, LT>(f, x);
    }
#endif
    if (w == 1) solve_permuted<1, 1, LT>(f, x);
    else if (w == 4) solve_permuted<4, 1, LT>(f, x);
    else if (w == 16) solve_permuted<4, 4, LT>(f, x);
    else solve_permuted<4, 2, LT>(f, x);
}


// ---- supernodal solves (supernodal_pass) ---------------------------------------------------
struct SupernodalFactor {
    int ns;
    const int *start, *rows_ptr, *rows;
    const size_t* val_ptr;
    const double* val;
    const float* val_single;
    const double* diag_inverse;  // 1 / L(c, c), per scalar column
    const int* diag_ptr;
    const double* diag_inverse_single;  // the same (set when val_single is)
    const unsigned char* wanted;  // null, or per supernode (as Factor::wanted)
    const Half* val_half;  // the half-precision copy: each scalar column over its scale, or null
    const float* scale;    // per scalar column (as diag_inverse), with val_half
    const unsigned char* part = nullptr;  // per supernode its part (BlockLDLT::sn_part_), with `only`
    int only = -1;                        // -1: every supernode, else only those of this part
    bool forward = true, backward = true;  // the passes to make
    const unsigned char* path = nullptr;   // null, or per supernode: the forward pass visits only these
    bool skips(int j) const { return only >= 0 && part[j] != only; }
};

template <typename PT> struct PanelVec;
template <> struct PanelVec<double> {
    typedef double F4 __attribute__((vector_size(32), aligned(8)));
    typedef double F8 __attribute__((vector_size(64), aligned(8)));
};
template <> struct PanelVec<float> {
    typedef float F4 __attribute__((vector_size(16), aligned(4)));
    typedef float F8 __attribute__((vector_size(32), aligned(4)));
};
template <int VL, typename PT>
__attribute__((always_inline)) inline typename Lanes<VL>::V load_panel(const PT* p) {
    typedef typename Lanes<VL>::V V;
    if constexpr (VL == 4) {
        typename PanelVec<PT>::F4 v;
        __builtin_memcpy(&v, p, sizeof v);
        return __builtin_convertvector(v, V);
    } else {
        typename PanelVec<PT>::F8 v;
        __builtin_memcpy(&v, p, sizeof v);
        return __builtin_convertvector(v, V);
    }
}
// one panel value as a double
template <typename PT>
__attribute__((always_inline)) inline double panel_value(const PT* p) {
    return static_cast<double>(*p);
}
// a SIMD value V from / to memory of its element type, unaligned
template <typename V>
__attribute__((always_inline)) inline V load_vector(const void* p) {
    V v;
    __builtin_memcpy(&v, p, sizeof v);
    return v;
}
template <typename V>
__attribute__((always_inline)) inline void store_vector(void* p, V v) {
    __builtin_memcpy(p, &v, sizeof v);
}

#ifdef HH_HAVE_F16C_KERNELS
// The float passes' helpers (supernodal_pass with AT = float): float vectors of VL lanes, half
// panels converted to floats.
template <int VL> struct FloatLanes;
template <> struct FloatLanes<4> { typedef float V __attribute__((vector_size(16))); };
template <> struct FloatLanes<8> { typedef HalfFloat8 V; };
template <> struct FloatLanes<16> { typedef HalfFloat16 V; };
template <int VL>
__attribute__((always_inline)) inline typename FloatLanes<VL>::V load_half_floats(const Half* p) {
    if constexpr (VL == 16) return load_half16_floats(p);
    else return load_half8_floats(p);
}
// Rows [r, ld) of a group's G half-precision columns in whole chunks of CH rows, as floats:
// use(row, v) with v[k][q] the value of column k at row + q. Each chunk is converted a chunk
// ahead of its use: converted just before, the scalar loads from the wide stores still in
// flight could not be forwarded and stalled (an 8-lane pass took 1.42x the float panels' time).
// Returns the first row of the tail left.
template <int CH, int G, class Use>
__attribute__((always_inline)) inline int half_chunks(const Half* const* col, int r, int ld, Use&& use) {
    float buf[2][G][CH];
    int b = 0;
    if (r + CH <= ld)
        for (int k = 0; k < G; ++k) store_vector(buf[0][k], load_half_floats<CH>(col[k] + r));
    for (; r + CH <= ld; r += CH, b ^= 1) {
        if (r + 2 * CH <= ld)
            for (int k = 0; k < G; ++k) store_vector(buf[b ^ 1][k], load_half_floats<CH>(col[k] + r + CH));
        use(r, buf[b]);
    }
    return r;
}
// one panel value as a float (a half still over its column's scale)
template <typename PT>
__attribute__((always_inline)) inline float panel_float(const PT* p) {
    if constexpr (std::is_same_v<PT, Half>) return half_float(*p);
    else return *p;
}
#endif

// The supernodal passes, one template for both arithmetics. AT: the arithmetic of x and y,
// double (the direct solves and the double-arithmetic preconditioner passes, on double or float
// panels) or float (the preconditioner passes where the CPU has AVX2, on half or float panels:
// the panels' own rounding, 2^-11 of each column's largest entry or 2^-24, is at or above
// float's, and the double kernels' time went to widening each value to a double). W lanes per
// row (1, 4, 8, 16 or 32; float: 1, 4 or 8); VL: the SIMD width along the rows when W = 1, and
// for half panels with W > 1 the rows a chunk holds (half_chunks). PT: the panels' type; half
// panels hold each column over its scale (f.scale), multiplied back as the values are used.
//
// Per supernode, the rows it touches are copied into one contiguous buffer y (its own rows,
// then its rows below), so that each column of the panel meets y as one contiguous run.
// Forward (L y = b): columns in groups of G, y_r -= sum_k P(r, c_k) y_{c_k} for the rows below
// the group, the group's values of every lane in registers; backward (L^T x = y): the G dot
// products of the group's columns with the rows below it, then the group's own triangle.
template <typename AT, int L> struct PassLanes;
template <int L> struct PassLanes<double, L> { typedef typename Lanes<L>::V V; };
#ifdef HH_HAVE_F16C_KERNELS
template <int L> struct PassLanes<float, L> { typedef typename FloatLanes<L>::V V; };
#endif
// VL consecutive panel values as the arithmetic's vector, and one as its scalar
template <typename AT, int VL, typename PT>
__attribute__((always_inline)) inline typename PassLanes<AT, VL>::V load_rows(const PT* p) {
    if constexpr (std::is_same_v<AT, double>) return load_panel<VL>(p);
#ifdef HH_HAVE_F16C_KERNELS
    else return load_half_floats<VL>(p);  // (float arithmetic takes one lane on the half panels only)
#endif
}
template <typename AT, typename PT>
__attribute__((always_inline)) inline AT panel_scalar(const PT* p) {
    if constexpr (std::is_same_v<AT, double>) return panel_value(p);
#ifdef HH_HAVE_F16C_KERNELS
    else return panel_float(p);
#endif
}

template <typename AT, int W, int VL, typename PT>
__attribute__((always_inline)) inline void supernodal_pass(const SupernodalFactor& f, const PT* val, const double* dinv_all,
                                                           AT* x, AT* y) {
    constexpr bool kFloat = std::is_same_v<AT, float>;
    constexpr bool kScaled = std::is_same_v<PT, Half>;
    static_assert(!kFloat || kScaled || W > 1, "one lane in float on the half panels only");
    // W = 1: V has VL lanes along the rows. W > 1: each row's W values are N vectors of LV
    // lanes (double: LV = min(W, VL), two 4-lane vectors per row for W = 8 with AVX2; float: one)
    constexpr int LV = W == 1 ? VL : (kFloat ? W : (W < VL ? W : VL));
    constexpr int N = W == 1 ? 1 : W / LV;
    typedef typename PassLanes<AT, LV>::V V;
    // columns per group: the group's values of every lane stay in registers (G x N vectors)
    constexpr int G = W == 1 ? 4 : (W <= 8 ? 8 : 4);
    // Vectors of lanes one sweep over a group's rows below takes (W > 1): all N when the G x N
    // values or sums fit the registers with room to spare (16 with AVX2's 4 doubles, 32 with
    // AVX-512's 8), else 2 per sweep: with AVX2, 16 and 32 lanes spilled them (the grasping
    // hand's 32 dense columns in 16-lane passes: 3.75 ms in whole sweeps, 3.35 ms in chunks, one
    // core; the same values bit for bit)
    constexpr int kRegisters = VL >= 8 ? 32 : 16;
    constexpr int QB = (W == 1 || G * N <= kRegisters - 4 || N % 2 != 0) ? N : 2;
    constexpr int CH = VL;  // half panels, W > 1: rows converted a chunk at a time
    // a value times its column's scale (half panels; the other panels hold the values themselves)
    auto scaled = [](auto v, float s) {
        if constexpr (kScaled) return v * s;
        else return v;
    };
    // supernode j: its m columns and nr rows (its own first), its panels, 1 / L(c, c), scales, x
    struct Supernode {
        int m, nr;
        const int* rows;
        const PT* p;
        const double* dinv;
        const float* scale;
        AT* xj;
    };
    auto supernode = [&](int j) {
        const int c0 = f.start[j];
        return Supernode{3 * (f.start[j + 1] - c0), f.rows_ptr[j + 1] - f.rows_ptr[j], f.rows + f.rows_ptr[j],
                         val + f.val_ptr[j], dinv_all + f.diag_ptr[j], kScaled ? f.scale + f.diag_ptr[j] : nullptr,
                         x + static_cast<size_t>(W) * 3 * c0};
    };
    // the g (<= G) columns from c: their panels and scales (the last repeated up to G)
    auto group = [&](const Supernode& n, int c, int g, const PT** col, float* s) {
        for (int k = 0; k < G; ++k) {
            col[k] = n.p + static_cast<size_t>(3 * n.nr) * (c + std::min(k, g - 1));
            s[k] = kScaled ? n.scale[c + std::min(k, g - 1)] : 1.0f;
        }
    };
    for (int j = 0; j < (f.forward ? f.ns : 0); ++j) {  // L z = b
        if (f.skips(j) || (f.path && !f.path[j])) continue;
        const Supernode n = supernode(j);
        const int m = n.m, nr = n.nr, ld = 3 * nr;
        AT* xj = n.xj;
        if (!f.path) {  // all of the supernode's values still zero: nothing to add below (see solve_permuted)
            const size_t total = static_cast<size_t>(W) * m;
            size_t e = 0;
            while (e < total && xj[e] == 0) ++e;
            if (e == total) continue;
        }
        std::copy(xj, xj + static_cast<size_t>(W) * m, y);
        std::fill(y + static_cast<size_t>(W) * m, y + static_cast<size_t>(W) * ld, AT(0));
        for (int c = 0; c < m; c += G) {
            const int g = std::min(G, m - c);
            const PT* col[G];
            float s[G];
            group(n, c, g, col, s);
            for (int k = 0; k < g; ++k) {  // the group's triangle
                AT* yk = y + static_cast<size_t>(W) * (c + k);
                const AT d = static_cast<AT>(n.dinv[c + k]);
                for (int e = 0; e < W; ++e) yk[e] *= d;
                for (int k2 = k + 1; k2 < g; ++k2) {
                    const AT l = scaled(panel_scalar<AT>(col[k] + c + k2), s[k]);
                    AT* y2 = y + static_cast<size_t>(W) * (c + k2);
                    for (int e = 0; e < W; ++e) y2[e] -= l * yk[e];
                }
            }
            int r = c + g;
            if constexpr (W == 1) {
                AT a[G];
                for (int k = 0; k < G; ++k) a[k] = k < g ? scaled(y[c + k], s[k]) : AT(0);
                for (; r + VL <= ld; r += VL) {
                    const V t = load_rows<AT, VL>(col[0] + r) * a[0] + load_rows<AT, VL>(col[1] + r) * a[1] +
                                load_rows<AT, VL>(col[2] + r) * a[2] + load_rows<AT, VL>(col[3] + r) * a[3];
                    store_vector(y + r, load_vector<V>(y + r) - t);
                }
                for (; r < ld; ++r)
                    y[r] -= panel_scalar<AT>(col[0] + r) * a[0] + panel_scalar<AT>(col[1] + r) * a[1] +
                            panel_scalar<AT>(col[2] + r) * a[2] + panel_scalar<AT>(col[3] + r) * a[3];
            } else {
                V a[G][N];
                for (int k = 0; k < G; ++k)
                    for (int q = 0; q < N; ++q)
                        a[k][q] = k < g ? scaled(load_vector<V>(y + W * (c + k) + LV * q), s[k]) : V{} * AT(0);
#ifdef HH_HAVE_F16C_KERNELS
                if constexpr (kScaled)
                    r = half_chunks<CH, G>(col, r, ld, [&](int r0, const float (&v)[G][CH]) {
                        for (int q = 0; q < CH; ++q) {
                            V t = v[0][q] * a[0][0];
                            for (int k = 1; k < G; ++k) t += v[k][q] * a[k][0];
                            store_vector(y + W * (r0 + q), load_vector<V>(y + W * (r0 + q)) - t);
                        }
                    });
#endif
                // QB of the N vectors per sweep over the rows (see QB): each lane's
                // arithmetic is the same whatever the chunk
                for (int q0 = 0; q0 < N; q0 += QB) {
                    V ac[G][QB];
                    for (int k = 0; k < G; ++k)
                        for (int q = 0; q < QB; ++q) ac[k][q] = a[k][q0 + q];
                    for (int r2 = r; r2 < ld; ++r2) {
                        AT* yr = y + static_cast<size_t>(W) * r2 + LV * q0;
                        for (int q = 0; q < QB; ++q) {
                            V t = panel_scalar<AT>(col[0] + r2) * ac[0][q];
                            for (int k = 1; k < G; ++k) t += panel_scalar<AT>(col[k] + r2) * ac[k][q];
                            store_vector(yr + LV * q, load_vector<V>(yr + LV * q) - t);
                        }
                    }
                }
            }
        }
        std::copy(y, y + static_cast<size_t>(W) * m, xj);
        for (int t = m / 3; t < nr; ++t) {
            AT* to = x + static_cast<size_t>(W) * 3 * n.rows[t];
            const AT* from = y + static_cast<size_t>(W) * 3 * t;
            for (int e = 0; e < 3 * W; ++e) to[e] += from[e];
        }
    }
    for (int j = f.backward ? f.ns - 1 : -1; j >= 0; --j) {  // L^T x = z
        if ((f.wanted && !f.wanted[j]) || f.skips(j)) continue;  // (see solve_permuted)
        const Supernode n = supernode(j);
        const int m = n.m, nr = n.nr, ld = 3 * nr;
        AT* xj = n.xj;
        std::copy(xj, xj + static_cast<size_t>(W) * m, y);
        for (int t = m / 3; t < nr; ++t) {
            const AT* from = x + static_cast<size_t>(W) * 3 * n.rows[t];
            AT* to = y + static_cast<size_t>(W) * 3 * t;
            for (int e = 0; e < 3 * W; ++e) to[e] = from[e];  // inline: a call per row costs more
        }
        for (int c = ((m - 1) / G) * G; c >= 0; c -= G) {
            const int g = std::min(G, m - c);
            const PT* col[G];
            float s[G];
            group(n, c, g, col, s);
            int r = c + g;
            AT acc[G][W];
            if constexpr (W == 1) {
                V s0 = V{} * AT(0), s1 = s0, s2 = s0, s3 = s0;
                for (; r + VL <= ld; r += VL) {
                    const V yr = load_vector<V>(y + r);
                    s0 += load_rows<AT, VL>(col[0] + r) * yr;
                    s1 += load_rows<AT, VL>(col[1] + r) * yr;
                    s2 += load_rows<AT, VL>(col[2] + r) * yr;
                    s3 += load_rows<AT, VL>(col[3] + r) * yr;
                }
                AT t[G] = {0, 0, 0, 0};
                for (int e = 0; e < VL; ++e) {
                    t[0] += s0[e];
                    t[1] += s1[e];
                    t[2] += s2[e];
                    t[3] += s3[e];
                }
                // the rows left: in float each product is rounded before its sum, as the float
                // passes have always computed them (whether the compiler fuses the two depends on
                // how it vectorizes this loop; the barrier keeps the results the same bit for bit)
                for (; r < ld; ++r)
                    for (int k = 0; k < G; ++k) {
                        AT product = panel_scalar<AT>(col[k] + r) * y[r];
#ifdef HH_HAVE_F16C_KERNELS
                        if constexpr (kFloat) asm("" : "+x"(product));
#endif
                        t[k] += product;
                    }
                for (int k = 0; k < G; ++k) acc[k][0] = scaled(t[k], s[k]);
            } else {
                V sk[G][N];
                for (int k = 0; k < G; ++k)
                    for (int q = 0; q < N; ++q) sk[k][q] = V{} * AT(0);
#ifdef HH_HAVE_F16C_KERNELS
                if constexpr (kScaled)
                    r = half_chunks<CH, G>(col, r, ld, [&](int r0, const float (&v)[G][CH]) {
                        for (int q = 0; q < CH; ++q) {
                            const V yr = load_vector<V>(y + W * (r0 + q));
                            for (int k = 0; k < G; ++k) sk[k][0] += v[k][q] * yr;
                        }
                    });
#endif
                for (int q0 = 0; q0 < N; q0 += QB) {  // (as the forward pass's chunks)
                    V sc[G][QB];
                    for (int k = 0; k < G; ++k)
                        for (int q = 0; q < QB; ++q) sc[k][q] = sk[k][q0 + q];
                    for (int r2 = r; r2 < ld; ++r2)
                        for (int q = 0; q < QB; ++q) {
                            const V yr = load_vector<V>(y + static_cast<size_t>(W) * r2 + LV * (q0 + q));
                            for (int k = 0; k < G; ++k) sc[k][q] += panel_scalar<AT>(col[k] + r2) * yr;
                        }
                    for (int k = 0; k < G; ++k)
                        for (int q = 0; q < QB; ++q) sk[k][q0 + q] = sc[k][q];
                }
                for (int k = 0; k < G; ++k)
                    for (int q = 0; q < N; ++q) store_vector(acc[k] + LV * q, scaled(sk[k][q], s[k]));
            }
            for (int k = g - 1; k >= 0; --k) {  // the group's triangle, last column first
                AT* yk = y + static_cast<size_t>(W) * (c + k);
                AT v[W];  // lanes innermost, so the loops vectorize (same order of operations per lane)
                for (int e = 0; e < W; ++e) v[e] = yk[e] - acc[k][e];
                for (int k2 = k + 1; k2 < g; ++k2) {
                    const AT l = scaled(panel_scalar<AT>(col[k] + c + k2), s[k]);
                    const AT* y2 = y + static_cast<size_t>(W) * (c + k2);
                    for (int e = 0; e < W; ++e) v[e] -= l * y2[e];
                }
                const AT d = static_cast<AT>(n.dinv[c + k]);
                for (int e = 0; e < W; ++e) yk[e] = v[e] * d;
            }
        }
        std::copy(y, y + static_cast<size_t>(W) * m, xj);
    }
}

#ifdef HH_HAVE_SIMD_KERNELS
template <int W, int VL, typename PT>
__attribute__((target("avx2,fma"))) void supernodal_avx2(const SupernodalFactor& f, const PT* v, const double* d, double* x, double* y) {
    supernodal_pass<double, W, VL, PT>(f, v, d, x, y);
}
template <int W, int VL, typename PT>
__attribute__((target("avx512f,avx512vl,avx2,fma"))) void supernodal_avx512(const SupernodalFactor& f, const PT* v, const double* d,
                                                                           double* x, double* y) {
    supernodal_pass<double, W, VL, PT>(f, v, d, x, y);
}
#endif

#ifdef HH_HAVE_F16C_KERNELS
// the float passes' panels: the half copy or the single one
template <typename PT>
const PT* float_panels(const SupernodalFactor& f) {
    if constexpr (std::is_same_v<PT, Half>) return f.val_half;
    else return f.val_single;
}
template <int W, int VL, typename PT>
__attribute__((target("avx2,fma,f16c"), flatten)) void supernodal_avx2_float(const SupernodalFactor& f, float* x, float* y) {
    supernodal_pass<float, W, VL, PT>(f, float_panels<PT>(f), f.diag_inverse_single, x, y);
}
template <int W, int VL, typename PT>
__attribute__((target("avx512f,avx512vl,avx2,fma,f16c"), flatten)) void supernodal_avx512_float(const SupernodalFactor& f,
                                                                                             float* x, float* y) {
    supernodal_pass<float, W, VL, PT>(f, float_panels<PT>(f), f.diag_inverse_single, x, y);
}
// false when the kernels cannot run here (no AVX2)
bool supernodal_float(const SupernodalFactor& f, float* x, int w, float* y) {
    const int level = simd_level();
    const bool half = f.val_half != nullptr;
    if (level == 2) {
        if (w == 1) supernodal_avx512_float<1, 16, Half>(f, x, y);
        else if (w == 4) half ? supernodal_avx512_float<4, 16, Half>(f, x, y) : supernodal_avx512_float<4, 16, float>(f, x, y);
        else half ? supernodal_avx512_float<8, 16, Half>(f, x, y) : supernodal_avx512_float<8, 16, float>(f, x, y);
        return true;
    }
    if (level == 1) {
        if (w == 1) supernodal_avx2_float<1, 8, Half>(f, x, y);
        else if (w == 4) half ? supernodal_avx2_float<4, 8, Half>(f, x, y) : supernodal_avx2_float<4, 8, float>(f, x, y);
        else half ? supernodal_avx2_float<8, 8, Half>(f, x, y) : supernodal_avx2_float<8, 8, float>(f, x, y);
        return true;
    }
    return false;
}
#endif

template <typename PT>
void supernodal_dispatch_typed(const SupernodalFactor& f, const PT* v, const double* d, double* x, int w, double* y) {
#ifdef HH_HAVE_SIMD_KERNELS
    const int level = simd_level();
    if (level == 2) {
        if (w == 1) return supernodal_avx512<1, 8, PT>(f, v, d, x, y);
        if (w == 4) return supernodal_avx512<4, 4, PT>(f, v, d, x, y);
        if (w == 16) return supernodal_avx512<16, 8, PT>(f, v, d, x, y);
        if (w == 32) return supernodal_avx512<32, 8, PT>(f, v, d, x, y);
        return supernodal_avx512<8, 8, PT>(f, v, d, x, y);
    }
    if (level == 1) {
        if (w == 1) return supernodal_avx2<1, 4, PT>(f, v, d, x, y);
        if (w == 4) return supernodal_avx2<4, 4, PT>(f, v, d, x, y);
        if (w == 16) return supernodal_avx2<16, 4, PT>(f, v, d, x, y);
        if (w == 32) return supernodal_avx2<32, 4, PT>(f, v, d, x, y);
        return supernodal_avx2<8, 4, PT>(f, v, d, x, y);
    }
#endif
    if (w == 1) supernodal_pass<double, 1, 4, PT>(f, v, d, x, y);
    else if (w == 4) supernodal_pass<double, 4, 4, PT>(f, v, d, x, y);
    else if (w == 16) supernodal_pass<double, 16, 4, PT>(f, v, d, x, y);
    else if (w == 32) supernodal_pass<double, 32, 4, PT>(f, v, d, x, y);
    else supernodal_pass<double, 8, 4, PT>(f, v, d, x, y);
}

void supernodal_solve_dispatch(const SupernodalFactor& f, double* x, int w, double* y) {
    // (half panels come here only where the float passes cannot run, BlockLDLT::float_passes:
    // their single-precision copy serves then)
    if (f.val_single) supernodal_dispatch_typed<float>(f, f.val_single, f.diag_inverse_single, x, w, y);
    else supernodal_dispatch_typed<double>(f, f.val, f.diag_inverse, x, w, y);
}

}  // namespace

void multiply_node_major(const SpMat& a, const double* x, double* y, int w) {
    multiply_node_major(a, x, y, w, 0, static_cast<int>(a.cols() / 3));
}

void multiply_node_major(const SpMat& a, const double* x, double* y, int w, int first_node, int end_node) {
    if (w != 1 && w != 4 && w != 8) throw std::logic_error("multiply_node_major: width must be 1, 4 or 8");
    if (first_node < 0 || end_node > a.cols() / 3 || first_node > end_node) throw std::logic_error("multiply_node_major: no such nodes");
    // (each node's rows from its own column, A symmetric: a range of nodes is its rows alone)
    const int n = end_node - first_node;
    y += static_cast<size_t>(3) * w * first_node;
    const int* o = a.outerIndexPtr() + 3 * static_cast<size_t>(first_node);
    const int* i = a.innerIndexPtr();
    const double* v = a.valuePtr();
#ifdef HH_HAVE_SIMD_KERNELS
    const int level = simd_level();
    if (level == 2) {
        if (w == 1) return multiply_avx512<1, 1>(n, o, i, v, x, y);
        if (w == 4) return multiply_avx512<4, 1>(n, o, i, v, x, y);
        return multiply_avx512<8, 1>(n, o, i, v, x, y);
    }
    if (level == 1) {
        if (w == 1) return multiply_avx2<1, 1>(n, o, i, v, x, y);
        if (w == 4) return multiply_avx2<4, 1>(n, o, i, v, x, y);
        return multiply_avx2<4, 2>(n, o, i, v, x, y);
    }
#endif
    if (w == 1) multiply_blocks<1, 1>(n, o, i, v, x, y);
    else if (w == 4) multiply_blocks<4, 1>(n, o, i, v, x, y);
    else multiply_blocks<4, 2>(n, o, i, v, x, y);
}

bool has_node_block_pattern(const SpMat& a) {
    if (a.rows() != a.cols() || a.cols() % 3 != 0 || !a.isCompressed()) return false;
    const int* o = a.outerIndexPtr();
    const int* in = a.innerIndexPtr();
    for (Eigen::Index j = 0; j < a.cols() / 3; ++j) {
        const int len = o[3 * j + 1] - o[3 * j];
        if (len % 3 != 0) return false;
        for (int c = 1; c < 3; ++c)
            if (o[3 * j + c + 1] - o[3 * j + c] != len) return false;
        for (int k = 0; k < len; ++k) {
            const int row = in[o[3 * j] + k];
            if (row % 3 != k % 3 || (k % 3 != 0 && row != in[o[3 * j] + k - 1] + 1)) return false;
            for (int c = 1; c < 3; ++c)
                if (in[o[3 * j + c] + k] != row) return false;
        }
    }
    return true;
}

namespace {
// x = P W^T b (in) and back, b = W P^T x (out), for W lanes per row known at compile time
// (the loops vectorize over the lanes; the warp: a 3x3 rotation per node, or none).
template <int W, bool In>
void warp_permute(int n, const int* order, const std::vector<Mat3>* warp, const double* from, double* to) {
    for (int node = 0; node < n; ++node) {
        const int old = order[node];
        const double* src = from + 3 * W * (In ? old : node);
        double* dst = to + 3 * W * (In ? node : old);
        if (!warp) {
            for (int e = 0; e < 3 * W; ++e) dst[e] = src[e];
            continue;
        }
        const double* m = (*warp)[old].data();  // column-major: W(r, c) = m[r + 3 c]
        for (int r = 0; r < 3; ++r) {
            // row r of W^T (in) or of W (out)
            const double m0 = In ? m[3 * r] : m[r], m1 = In ? m[3 * r + 1] : m[r + 3], m2 = In ? m[3 * r + 2] : m[r + 6];
            for (int j = 0; j < W; ++j) dst[r * W + j] = m0 * src[j] + m1 * src[W + j] + m2 * src[2 * W + j];
        }
    }
}
}  // namespace

void BlockLDLT::solve_node_major(double* b, int w, const std::vector<Mat3>* warp, Panels panels) const {
    solve_node_major(b, w, warp, panels, nullptr);
}

// The solves' scratch is per thread, not per factor: solves on one factor may run on two
// threads at once (a soft body's contact responses split between the world's threads,
// World::step), and the factor itself is only read. Each thread's buffers grow to the largest
// solve it has made and are then reused (no allocation per solve once warm).
namespace {
struct SolveScratch {
    std::vector<double> work, packed, gather;
    // solve_units' right-hand sides, all zero between its calls (each call zeroes what it
    // wrote), so a call lays out its columns without clearing 3n x w values first
    std::vector<double> units;
    bool units_clear = true;
    std::vector<double> saved, copy;  // solve_node_major_split: the rest's right-hand rows; part 1's copy
    std::vector<float> work_f, gather_f, saved_f, copy_f;  // the same for the float passes (float_passes)
    std::vector<unsigned char> wanted_node, wanted_sn;
    std::vector<int> dirty;
    std::vector<unsigned char> path;  // unit_path's mask: the last call's path (the next call clears it)
    std::vector<int> path_set;        // the supernodes it set
};
// Lanes of a solve pass for k right-hand sides: the kernels' widths (1, 4, 8; 16, 32 supernodal)
int padded_width(int k) { return k == 1 ? 1 : (k <= 4 ? 4 : (k <= 8 ? 8 : (k <= 16 ? 16 : 32))); }
SolveScratch& scratch() {
    thread_local SolveScratch s;
    return s;
}
}  // namespace

// The forward, diagonal and backward passes on x in the factor's own node order
void BlockLDLT::check_panels(int w, Panels panels) const {
    if (panels == Panels::Half && !half_valid_)
        throw std::logic_error("BlockLDLT::solve_node_major: no half-precision copy of the factor");
    if (panels == Panels::Half && !(w == 1 || w == 4 || w == 8))
        throw std::logic_error("BlockLDLT::solve_node_major: half-precision passes take 1, 4 or 8 columns");
    // (half falls back on single where it cannot run)
    if (panels != Panels::Double && !single_valid_)
        throw std::logic_error("BlockLDLT::solve_node_major: no single-precision copy of the factor");
}

void BlockLDLT::solve_in_order(double* x, int w, Panels panels, const unsigned char* wanted, const unsigned char* path) const {
    check_panels(w, panels);
    const bool single = panels != Panels::Double;
    if (supernodal_) {
        solve_supernodal(x, w, panels, wanted, -1, true, true, path);
    } else if (single) {
        const Factor<float> f{n_, lp_.data(), lnz_.data(), li_.data(), lx_single_.data(), d_inverse_single_.data(), wanted, path};
        solve_dispatch(f, x, w);
    } else {
        const Factor<double> f{n_, lp_.data(), lnz_.data(), li_.data(), lx_.empty() ? nullptr : lx_[0].data(), d_inverse_[0].data(), wanted, path};
        solve_dispatch(f, x, w);
    }
}

namespace {
// to = W^T from in the factor's node order (in), or back (out); see warp_permute
void warp_permute_any(int w, bool in, int n, const int* order, const std::vector<Mat3>* warp, const double* from, double* to) {
    if (w == 1) in ? warp_permute<1, true>(n, order, warp, from, to) : warp_permute<1, false>(n, order, warp, from, to);
    else if (w == 4) in ? warp_permute<4, true>(n, order, warp, from, to) : warp_permute<4, false>(n, order, warp, from, to);
    else if (w == 16) in ? warp_permute<16, true>(n, order, warp, from, to) : warp_permute<16, false>(n, order, warp, from, to);
    else if (w == 32) in ? warp_permute<32, true>(n, order, warp, from, to) : warp_permute<32, false>(n, order, warp, from, to);
    else in ? warp_permute<8, true>(n, order, warp, from, to) : warp_permute<8, false>(n, order, warp, from, to);
}
}  // namespace

void BlockLDLT::solve_node_major(double* b, int w, const std::vector<Mat3>* warp, Panels panels,
                                 const unsigned char* wanted) const {
    if (!(w == 1 || w == 4 || w == 8 || (supernodal_ && (w == 16 || w == 32))))
        throw std::logic_error("BlockLDLT::solve_node_major: width must be 1, 4 or 8 (16 or 32: supernodal form only)");
    SolveScratch& s = scratch();
    s.work.resize(static_cast<size_t>(3) * n_ * w);
    double* x = s.work.data();
    warp_permute_any(w, true, n_, order_.data(), warp, b, x);
    if (float_passes(w, panels)) {
        s.work_f.assign(x, x + static_cast<size_t>(3) * n_ * w);
        solve_supernodal(s.work_f.data(), w, panels, wanted);
        std::copy(s.work_f.begin(), s.work_f.end(), x);
    } else {
        solve_in_order(x, w, panels, wanted);
    }
    warp_permute_any(w, false, n_, order_.data(), warp, x, b);
}

bool BlockLDLT::float_passes(int w, Panels panels) const {
#ifdef HH_HAVE_F16C_KERNELS
    if (!supernodal_ || simd_level() == 0) return false;
    return (panels == Panels::Half && half_valid_ && (w == 1 || w == 4 || w == 8)) ||
           ((w == 4 || w == 8) && panels == Panels::Single && single_valid_);
#else
    (void)w;
    (void)panels;
    return false;
#endif
}

namespace {
// The passes of solve_node_major_split on x (node-major, `row` values a node, in the factor's
// order): the forward passes of parts 0 and 1 as two jobs, part 1's on a copy; the rest's rows
// then sum what the right-hand side had, part 0's and part 1's contributions; the rest's passes;
// the backward passes of parts 0 and 1 as two jobs. pass(x, part, forward, backward).
template <typename T, class Pass>
void split_passes(T* x, size_t row, int ns, const int* sn_start, const unsigned char* sn_part, std::vector<T>& saved,
                  std::vector<T>& copy, const Beside& beside, const Pass& pass) {
    // the rest's rows start at zero in both copies (part 1's forward pass runs on its own)
    saved.clear();
    for (int j = 0; j < ns; ++j)
        if (sn_part[j] == 2) {
            T* from = x + row * sn_start[j];
            T* to = x + row * sn_start[j + 1];
            saved.insert(saved.end(), from, to);
            std::fill(from, to, T(0));
        }
    copy.assign(x, x + row * sn_start[ns]);
    T* x1 = copy.data();
    beside([&] { pass(x, 0, true, false); }, [&] { pass(x1, 1, true, false); });
    size_t k = 0;
    for (int j = 0; j < ns; ++j) {
        const size_t from = row * sn_start[j], to = row * sn_start[j + 1];
        if (sn_part[j] == 1) {
            std::copy(x1 + from, x1 + to, x + from);
        } else if (sn_part[j] == 2) {  // what the right-hand side had, then part 0's, then part 1's
            for (size_t e = from; e < to; ++e) x[e] = (saved[k++] + x[e]) + x1[e];
        }
    }
    pass(x, 2, true, true);
    beside([&] { pass(x, 0, false, true); }, [&] { pass(x, 1, false, true); });
}
}  // namespace

void BlockLDLT::solve_node_major_split(double* b, int w, const std::vector<Mat3>* warp, Panels panels, const Beside& beside) const {
    if (!supernodal_ || factor_parts_ != 2 || !beside) return solve_node_major(b, w, warp, panels);
    if (!(w == 1 || w == 4 || w == 8 || w == 16 || w == 32))
        throw std::logic_error("BlockLDLT::solve_node_major: width must be 1, 4, 8, 16 or 32");
    check_panels(w, panels);
    SolveScratch& s = scratch();  // (the caller's; the other job's kernels use their own thread's gather)
    const size_t row = static_cast<size_t>(3) * w;  // values per node
    s.work.resize(row * n_);
    double* x = s.work.data();
    warp_permute_any(w, true, n_, order_.data(), warp, b, x);
    auto pass = [&](auto* y, int part, bool forward, bool backward) {
        solve_supernodal(y, w, panels, nullptr, part, forward, backward);
    };
    if (float_passes(w, panels)) {
        s.work_f.assign(x, x + row * n_);
        split_passes(s.work_f.data(), row, supernodes(), sn_start_.data(), sn_part_.data(), s.saved_f, s.copy_f, beside, pass);
        std::copy(s.work_f.begin(), s.work_f.end(), x);
    } else {
        split_passes(x, row, supernodes(), sn_start_.data(), sn_part_.data(), s.saved, s.copy, beside, pass);
    }
    warp_permute_any(w, false, n_, order_.data(), warp, x, b);
}

void BlockLDLT::solve_units(const int* units, int k, const std::vector<int>& rows, const std::vector<int>& wanted_nodes,
                            double* out, long ld, int first_batch, int batch_step) const {
    if (first_batch < 0 || batch_step < 1) throw std::logic_error("BlockLDLT::solve_units: no such batches");
    const unsigned char* wanted = wanted_mask(wanted_nodes);
    // The nodes a pass may leave nonzero: the wanted ones and their ancestors (the backward
    // pass), which hold the units' ancestors (the forward pass); with supernodes, whole
    // supernodes. After each pass only they are zeroed again, not all 3n x w.
    std::vector<int>& dirty = scratch().dirty;
    dirty.clear();
    if (!supernodal_) {
        for (int i = 0; i < n_; ++i)
            if (scratch().wanted_node[i]) dirty.push_back(i);
    } else {
        for (int j = 0; j < supernodes(); ++j)
            if (scratch().wanted_sn[j])
                for (int i = sn_start_[j]; i < sn_start_[j + 1]; ++i) dirty.push_back(i);
    }
    // Up to 16 unit columns a pass on the up-looking factor (8 for its other solves): the
    // paper-size hands' factors stay in cache, so a pass is bound by its arithmetic, and two
    // vectors of lanes per row give each 3x3 block's loads twice the work (the paper bunny's
    // contact build is a few percent cheaper than with 8).
    const int most = supernodal_ ? widest_pass() : 16;
    // The right-hand sides stay zero between calls: each batch clears the dirty nodes it leaves
    // nonzero. Clearing all 3n x w values per call instead (the calls mostly take one batch)
    // had been ~1% of the 10x bunny's thread time: 3.2 MB per batch on the ~17000-tet hand, 26
    // batches when a renewal re-solves its responses. A call that throws leaves the buffer to
    // be cleared whole by the next one.
    SolveScratch& s = scratch();
    const size_t size = static_cast<size_t>(3) * n_ * padded_width(std::min(most, k));
    if (!s.units_clear || s.units.size() < size) s.units.assign(std::max(size, s.units.size()), 0.0);
    s.units_clear = false;
    for (int first = first_batch * most; first < k; first += batch_step * most) {
        const int c = std::min(most, k - first);
        const int w = padded_width(c);
        // straight in the factor's node order (node i's 3 x w values at 3 w i): no full-length
        // right-hand side to build, permute and copy back
        double* x = s.units.data();
        auto at = [&](int unknown) {
            if (unknown < 0 || unknown >= 3 * n_) throw std::logic_error("BlockLDLT::solve_units: an unknown out of range");
            return static_cast<size_t>(w) * (3 * static_cast<size_t>(inverse_[unknown / 3]) + unknown % 3);
        };
        for (int j = 0; j < c; ++j) {
            const size_t e = at(units[first + j]);
            // a unit outside the wanted nodes would be left behind by the clearing below
            if (!s.wanted_node[inverse_[units[first + j] / 3]])
                throw std::logic_error("BlockLDLT::solve_units: a unit's node is not among the wanted nodes");
            x[e + j] = 1.0;
        }
        solve_in_order(x, w, Panels::Double, wanted, unit_path(units + first, c));
        for (int j = 0; j < c; ++j) {
            double* o = out + static_cast<size_t>(first + j) * ld;
            for (size_t r = 0; r < rows.size(); ++r) o[r] = x[at(rows[r]) + j];
        }
        // (the units' nodes are among the dirty ones: they are wanted)
        for (int i : dirty) std::fill_n(x + static_cast<size_t>(3) * w * i, 3 * w, 0.0);
    }
    s.units_clear = true;
}

// The nodes (supernodal form: supernodes) holding the units' nodes and their ancestors: a unit
// right-hand side is zero elsewhere throughout the forward pass. Scanning every node's values
// for zeros instead read all 3n x w of them per batch (on the grasping hand ~0.13 ms a batch of
// 32, a third of the forward pass, and the hand's contact build 1.1 ms faster without it).
const unsigned char* BlockLDLT::unit_path(const int* units, int k) const {
    SolveScratch& s = scratch();
    for (int j : s.path_set) s.path[j] = 0;
    s.path_set.clear();
    s.path.resize(supernodal_ ? supernodes() : n_, 0);
    auto up = [&](int j) {  // the parent supernode or node, or -1
        if (!supernodal_) return parent_[j];
        const int node = parent_[sn_start_[j + 1] - 1];
        return node < 0 ? -1 : node_sn_[node];
    };
    for (int u = 0; u < k; ++u) {
        const int node = inverse_[units[u] / 3];
        for (int j = supernodal_ ? node_sn_[node] : node; j >= 0 && !s.path[j]; j = up(j)) {
            s.path[j] = 1;
            s.path_set.push_back(j);
        }
    }
    return s.path.data();
}

VecX BlockLDLT::solve(const VecX& b) const {
    MatX x = b;
    solve(x, nullptr);
    return x.col(0);
}

void BlockLDLT::solve(MatX& b) const { solve(b, nullptr); }

void BlockLDLT::solve(MatX& b, const std::vector<Mat3>* warp) const { solve(b, warp, nullptr); }

// The wanted nodes and all their elimination-tree ancestors, as a mask over permuted nodes
// (and, for the supernodal form, over supernodes: a supernode's rows below are ancestors of
// all of its nodes, so a supernode holding a wanted node only reads wanted ones).
const unsigned char* BlockLDLT::wanted_mask(const std::vector<int>& nodes) const {
    std::vector<unsigned char>& wanted_node = scratch().wanted_node;
    wanted_node.assign(n_, 0);
    for (int old : nodes) {
        if (old < 0 || old >= n_) throw std::logic_error("BlockLDLT::solve: a wanted node out of range");
        for (int i = inverse_[old]; i >= 0 && !wanted_node[i]; i = parent_[i]) wanted_node[i] = 1;
    }
    if (!supernodal_) return wanted_node.data();
    const int ns = supernodes();
    std::vector<unsigned char>& wanted_sn = scratch().wanted_sn;
    wanted_sn.assign(ns, 0);
    for (int j = 0; j < ns; ++j)
        for (int i = sn_start_[j]; i < sn_start_[j + 1] && !wanted_sn[j]; ++i) wanted_sn[j] = wanted_node[i];
    return wanted_sn.data();
}

void BlockLDLT::solve(MatX& b, const std::vector<Mat3>* warp, const std::vector<int>* wanted_nodes) const {
    solve_packed(b, warp, wanted_nodes, nullptr);
}

void BlockLDLT::solve(MatX& b, const std::vector<Mat3>* warp, const Beside& beside) const {
    solve_packed(b, warp, nullptr, beside ? &beside : nullptr);
}

namespace {
// A node's 3 x W block (row-major) times W^T (in) or W (out), in place: warp_permute's
// arithmetic, for solve_packed's copies that permute and warp at once
template <int W, bool In>
void rotate_rows(const Mat3& warp, double* block) {
    double src[3 * W];
    std::copy(block, block + 3 * W, src);
    const double* m = warp.data();  // column-major: W(r, c) = m[r + 3 c]
    for (int r = 0; r < 3; ++r) {
        const double m0 = In ? m[3 * r] : m[r], m1 = In ? m[3 * r + 1] : m[r + 3], m2 = In ? m[3 * r + 2] : m[r + 6];
        for (int j = 0; j < W; ++j) block[r * W + j] = m0 * src[j] + m1 * src[W + j] + m2 * src[2 * W + j];
    }
}
template <bool In>
void rotate_rows(int w, const Mat3& warp, double* block) {
    if (w == 1) rotate_rows<1, In>(warp, block);
    else if (w == 4) rotate_rows<4, In>(warp, block);
    else if (w == 16) rotate_rows<16, In>(warp, block);
    else if (w == 32) rotate_rows<32, In>(warp, block);
    else rotate_rows<8, In>(warp, block);
}
}  // namespace

// Lanes of the supernodal form's double passes. With AVX2 a 32-lane pass keeps 8 vectors per row
// and 4 x 8 of a column group's values (the forward pass) or sums (the backward one): twice the
// 16 registers, so they spill; two 16-lane passes fit them and cost less, although each streams
// the factor (the grasping hand's 2078 nodes: 32 dense columns 4.6 ms in one pass, 3.8 ms in two,
// one core). Each lane's arithmetic is the same at either width, so the solutions are the same
// bit for bit. AVX-512 has 32 registers of 8 lanes: one pass.
int BlockLDLT::widest_pass() const {
    if (!supernodal_) return 8;
    return simd_level() == 1 ? 16 : kWidestSolve;
}

void BlockLDLT::solve_packed(MatX& b, const std::vector<Mat3>* warp, const std::vector<int>* wanted_nodes,
                             const Beside* beside) const {
    if (b.rows() != 3 * n_) throw std::logic_error("BlockLDLT::solve: right-hand side of the wrong size");
    const unsigned char* wanted = wanted_nodes ? wanted_mask(*wanted_nodes) : nullptr;
    // Columns per pass: the passes stream the factor from memory, so more columns share each
    // load (widest_pass).
    const int most = widest_pass();
    SolveScratch& s = scratch();
    for (Eigen::Index first = 0; first < b.cols(); first += most) {
        const int k = static_cast<int>(std::min<Eigen::Index>(most, b.cols() - first));
        const int w = padded_width(k);
        if (beside) {  // (the split passes permute their own copy)
            std::vector<double>& packed = s.packed;
            packed.resize(static_cast<size_t>(3) * n_ * w);
            pack_columns(b, first, k, w, packed.data());
            solve_node_major_split(packed.data(), w, warp, Panels::Double, *beside);
            unpack_columns(packed.data(), w, b, first, k);
            continue;
        }
        // Straight into the factor's node order, warped, and back: one copy each way (packing
        // node-major and then permuting made two, ~a fifth of the grasping hand's 32-lane pass)
        s.work.resize(static_cast<size_t>(3) * n_ * w);
        double* x = s.work.data();
        const double* in[kWidestSolve];
        double* out[kWidestSolve];
        for (int j = 0; j < k; ++j) in[j] = out[j] = b.col(first + j).data();
        for (int node = 0; node < n_; ++node) {
            const int old = order_[node];
            double* to = x + static_cast<size_t>(3) * w * node;
            for (int d = 0; d < 3; ++d) {
                double* row = to + static_cast<size_t>(w) * d;
                for (int j = 0; j < k; ++j) row[j] = in[j][3 * old + d];
                for (int j = k; j < w; ++j) row[j] = 0.0;
            }
            if (warp) rotate_rows<true>(w, (*warp)[old], to);
        }
        solve_in_order(x, w, Panels::Double, wanted);
        for (int node = 0; node < n_; ++node) {
            // with wanted nodes only theirs (whole supernodes: see wanted_mask) are asked for
            if (wanted && !wanted[supernodal_ ? node_sn_[node] : node]) continue;
            const int old = order_[node];
            double* from = x + static_cast<size_t>(3) * w * node;
            if (warp) rotate_rows<false>(w, (*warp)[old], from);
            for (int d = 0; d < 3; ++d) {
                const double* row = from + static_cast<size_t>(w) * d;
                for (int j = 0; j < k; ++j) out[j][3 * old + d] = row[j];
            }
        }
    }
}

// The node-major block of k columns of b from `first` (w lanes, the rest zero), and back
void BlockLDLT::pack_columns(const MatX& b, Eigen::Index first, int k, int w, double* packed) const {
    for (int e = 0; e < 3 * n_; ++e) {
        double* row = packed + static_cast<size_t>(w) * e;
        for (int j = 0; j < k; ++j) row[j] = b(e, first + j);
        for (int j = k; j < w; ++j) row[j] = 0.0;
    }
}

void BlockLDLT::unpack_columns(const double* packed, int w, MatX& b, Eigen::Index first, int k) const {
    for (int e = 0; e < 3 * n_; ++e) {
        const double* row = packed + static_cast<size_t>(w) * e;
        for (int j = 0; j < k; ++j) b(e, first + j) = row[j];
    }
}

template <typename T>
void BlockLDLT::solve_supernodal(T* x, int w, Panels panels, const unsigned char* wanted, int part, bool forward,
                                 bool backward, const unsigned char* path) const {
    const bool single = panels != Panels::Double, half = panels == Panels::Half;
    const int ns = supernodes();
    size_t most = 0;
    for (int j = 0; j < ns; ++j) most = std::max<size_t>(most, sn_rows_ptr_[j + 1] - sn_rows_ptr_[j]);
    const SupernodalFactor f{ns,
                             sn_start_.data(),
                             sn_rows_ptr_.data(),
                             sn_rows_.data(),
                             sn_val_ptr_.data(),
                             single ? nullptr : sn_val_.data(),
                             single ? sn_val_single_.data() : nullptr,
                             single ? nullptr : sn_diag_inverse_.data(),
                             sn_diag_ptr_.data(),
                             single ? sn_diag_inverse_.data() : nullptr,
                             wanted,
                             half ? sn_val_half_.data() : nullptr,
                             half ? sn_scale_.data() : nullptr,
                             sn_part_.data(),
                             part,
                             forward,
                             backward,
                             path};
    if constexpr (std::is_same_v<T, float>) {  // (float_passes)
        std::vector<float>& gather = scratch().gather_f;
        gather.resize(3 * most * w + 64);
#ifdef HH_HAVE_F16C_KERNELS
        if (supernodal_float(f, x, w, gather.data())) return;
#endif
        throw std::logic_error("BlockLDLT::solve_supernodal: no float passes on this CPU");
    } else {
        std::vector<double>& gather = scratch().gather;
        gather.resize(3 * most * w + 64);
        supernodal_solve_dispatch(f, x, w, gather.data());
    }
}

}  // namespace hh
