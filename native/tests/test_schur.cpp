// The Schur-complement solve (Eqs. 12-13, Section 6) against the monolithic reference of
// Eq. 7, and the handle's mass properties (Eq. 3).
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <functional>
#include <random>
#include <thread>

#include "box_mesh.h"
#include "check.h"
#include "common/simd.h"
#include "rigid/quaternion.h"
#include "sim/data.h"
#include "solver/block_ldlt.h"

using namespace hh;

namespace {
hh_params box_params() {
    hh_params p = box_hand_params();
    p.spring_stiffness = 1e5;
    p.spring_damping = 30;
    return p;
}
void perturb(Data& d, std::mt19937& rng) {
    std::normal_distribution<double> n(0, 1);
    for (int i = 0; i < d.x.size(); ++i) {
        d.x[i] += 1e-3 * n(rng);
        d.v[i] = 0.1 * n(rng);
    }
    d.h.x_com += Vec3(n(rng), n(rng), n(rng)) * 1e-3;
    d.h.q = quat_multiply(quat_from_rotation_vector(Vec3(n(rng), n(rng), n(rng)) * 0.1), d.h.q);
    d.h.v_com = Vec3(n(rng), n(rng), n(rng)) * 0.1;
    d.h.omega = Vec3(n(rng), n(rng), n(rng));
    d.device.enabled = true;
    d.device.position = d.h.x_com + Vec3(0.01, 0, 0);
    d.device.quaternion = quat_from_rotation_vector(Vec3(0.2, 0, 0));
}
// perturb, then the Schur step's system formed and solved
void solve_perturbed(const Model& m, Data& d, unsigned seed) {
    std::mt19937 rng(seed);
    perturb(d, rng);
    formulate(m, d);
    d.hand.solve();
}
// The 4 x 3 x 2 box hand after one perturbed solve (per-step Cholesky)
struct SolvedBoxHand {
    BoxMesh b = make_box(4, 3, 2, 0.01);
    Model m;
    Data d;
    explicit SolvedBoxHand(unsigned seed)
        : m(build_model(b.nodes.data(), b.n_nodes(), b.tets.data(), b.n_tets(), box_params())), d(m) {
        solve_perturbed(m, d, seed);
    }
};
// A 6 x 4 x 3 box hand on the reused factor, CG to 1e-10 (to compare with direct solves)
Model reused_box_model() {
    const BoxMesh b = make_box(6, 4, 3, 0.01);
    hh_params p = box_params();
    p.solver = HH_SOLVER_REUSED_CHOLESKY;
    p.cg_tolerance = 1e-10;
    return build_model(b.nodes.data(), b.n_nodes(), b.tets.data(), b.n_tets(), p);
}

// The device circling 3 cm around the handle's rest and turning (the reused factor's policy tests)
void wave_device(const Model& m, Data& d, int step) {
    const double t = step * m.params.dt;
    d.device.position = m.handle.rest_com + 0.03 * Vec3(std::cos(3 * t) - 1, std::sin(3 * t), 0.5 * std::sin(2 * t));
    d.device.quaternion = quat_from_rotation_vector(Vec3(0.6 * std::sin(2 * t), 0.4 * std::sin(1.5 * t), 1.5 * t));
}

double schur_vs_monolithic(int solver, double cg_tol, const FactorForms& forms = FactorForms()) {
    const BoxMesh b = make_box(4, 3, 2, 0.01);
    hh_params p = box_params();
    p.solver = solver;
    p.cg_tolerance = cg_tol;
    const Model m = build_model(b.nodes.data(), b.n_nodes(), b.tets.data(), b.n_tets(), p);
    Data d(m);
    d.tool.set_factor_forms(forms);
    solve_perturbed(m, d, 21);
    const VecX schur = d.hand.s;
    const VecX mono = solve_monolithic(d.hand, d.hand.r);
    return (schur - mono).cwiseAbs().maxCoeff() / mono.cwiseAbs().maxCoeff();
}
}  // namespace

TEST(schur_equals_monolithic_with_cholesky) { CHECK_LT(schur_vs_monolithic(HH_SOLVER_CHOLESKY, 1e-8), 1e-8); }

TEST(schur_equals_monolithic_with_the_supernodal_per_step_cholesky) {
    // large meshes factor every step in the supernodal form (L L^T in dense panels); forced here
    // on the small box, the Schur solve through it must still equal the monolithic reference
    FactorForms supernodal;
    supernodal.per_step = FactorForms::PerStep::Supernodal;
    CHECK_LT(schur_vs_monolithic(HH_SOLVER_CHOLESKY, 1e-8, supernodal), 1e-8);
}

TEST(schur_equals_monolithic_with_cg) { CHECK_LT(schur_vs_monolithic(HH_SOLVER_CG, 1e-14), 1e-8); }

TEST(handle_mass_and_inertia_follow_eq3) {
    const BoxMesh b = make_box(4, 3, 2, 0.01);
    const hh_params p = box_params();
    const Model m = build_model(b.nodes.data(), b.n_nodes(), b.tets.data(), b.n_tets(), p);
    double mass = 0;
    Vec3 com = Vec3::Zero();
    for (int i : m.handle.nodes) {
        mass += m.masses[i];
        com += m.masses[i] * m.mesh.rest.segment<3>(3 * i);
    }
    com /= mass;
    Mat3 inertia = Mat3::Zero();
    for (int i : m.handle.nodes) {
        const Vec3 r = m.mesh.rest.segment<3>(3 * i) - com;
        inertia += m.masses[i] * (r.squaredNorm() * Mat3::Identity() - r * r.transpose());
    }
    CHECK(m.handle.nodes.size() >= 4);
    CHECK_LT(std::abs(m.handle.mass - mass) / mass, 1e-14);
    CHECK_LT((m.handle.rest_com - com).norm(), 1e-15);
    CHECK_LT((m.handle.inertia_body - inertia).norm() / inertia.norm(), 1e-14);
    // every captured node is within the radius, every other node outside
    const Vec3 seed(p.palm_seed[0], p.palm_seed[1], p.palm_seed[2]);
    size_t inside = 0;
    for (int i = 0; i < m.mesh.n_nodes; ++i) inside += (m.mesh.rest.segment<3>(3 * i) - seed).norm() <= p.handle_radius;
    CHECK(inside == m.handle.nodes.size());
}

// HH_SOLVER_REUSED_CHOLESKY: CG preconditioned by the warped factor of an earlier step.
namespace {
struct ReuseRun {
    double worst = 0;          // largest |s - s_mono| / |s_mono| over the steps
    double worst_residual = 0; // largest relative residual of the At solves
    int iterations = 0, factorizations = 0, stale_steps = 0;
    // Eq. 7's residual of the step, flesh rows over the bound the At solves' tolerance allows
    // (see reused_cholesky_step_meets_a_loose_tolerance), and handle rows relative to |Ah v_h| + |b_h|
    double flesh_over_bound = 0, handle_residual = 0;
    VecX x;  // the flesh's positions at the end
};
// A box hand swung and turned by its device (about 2 rad over the run), solved with the reused
// factor; every step is checked against the monolithic reference before it is integrated.
ReuseRun reused_run(int iteration_limit, int steps, double tolerance = 1e-10, const Beside& beside = nullptr) {
    const BoxMesh b = make_box(6, 4, 3, 0.01);
    hh_params p = box_params();
    p.solver = HH_SOLVER_REUSED_CHOLESKY;
    p.cg_tolerance = tolerance;  // 1e-10: CG to round-off, to compare with the direct solves at 1e-8
    const Model m = build_model(b.nodes.data(), b.n_nodes(), b.tets.data(), b.n_tets(), p);
    Data d(m);
    d.tool.reuse_iteration_limit = iteration_limit;
    d.hand.beside = beside;
    d.device.enabled = true;
    ReuseRun out;
    for (int s = 0; s < steps; ++s) {
        const double t = s * p.dt;
        d.device.position = m.handle.rest_com + 0.03 * Vec3(std::cos(3 * t) - 1, std::sin(3 * t), 0.5 * std::sin(2 * t));
        d.device.quaternion = quat_from_rotation_vector(Vec3(0.6 * std::sin(2 * t), 0.4 * std::sin(1.5 * t), 1.5 * t));
        formulate(m, d);
        d.tool.reset_counters();
        d.hand.solve();
        const VecX mono = solve_monolithic(d.hand, d.hand.r);
        out.worst = std::max(out.worst, (d.hand.s - mono).cwiseAbs().maxCoeff() / mono.cwiseAbs().maxCoeff());
        // Eq. 7's residual. s_t = y - X v_h (Eq. 12) with y ~ A_t^-1 b_t and the columns X ~ A_t^-1 Ath,
        // each to a relative residual of at most the tolerance, so the flesh rows' residual
        // A_t s_t + Ath v_h - b_t = (A_t y - b_t) - sum_i v_h,i (A_t X_i - Ath_i) is at most
        // tol (|b_t| + sum_i |v_h,i| |Ath_i|); the handle rows are solved exactly through S = Ah - Aht X.
        const Eigen::Index n3 = d.tool.A.rows();
        const Vec6 vh = d.hand.s.head<6>();
        const VecX st = d.hand.s.tail(n3);
        VecX flesh = d.tool.A * st - d.hand.r.tail(n3);
        Vec6 handle = d.hand.Ah * vh - d.hand.r.head<6>();
        MatX ath = MatX::Zero(n3, 6);
        for (size_t j = 0; j < d.hand.coupled_nodes.size(); ++j) {
            const int k = d.hand.coupled_nodes[j];
            ath.block<3, 6>(3 * k, 0) = d.hand.Ath[j];
            handle += d.hand.Aht[j] * st.segment<3>(3 * k);
        }
        flesh += ath * vh;
        double bound = d.hand.r.tail(n3).norm();
        for (int i = 0; i < 6; ++i) bound += std::abs(vh[i]) * ath.col(i).norm();
        out.flesh_over_bound = std::max(out.flesh_over_bound, flesh.norm() / (tolerance * bound));
        out.handle_residual = std::max(out.handle_residual, handle.norm() / ((d.hand.Ah * vh).norm() + d.hand.r.head<6>().norm()));
        out.worst_residual = std::max(out.worst_residual, d.tool.max_residual);
        out.iterations += d.tool.iterations;
        out.factorizations += d.tool.factorizations;
        out.stale_steps += d.tool.iterations > 0;
        integrate(m, d, d.hand.s);
    }
    out.x = d.x;
    return out;
}
}  // namespace

TEST(reused_cholesky_equals_monolithic_while_the_hand_swings_and_turns) {
    const ReuseRun r = reused_run(25, 40);
    CHECK_LT(r.worst, 1e-8);
    CHECK_LT(r.worst_residual, 1e-10 * 1.0000001);
    CHECK(r.factorizations >= 1);
    CHECK(r.stale_steps >= 10);  // most steps ran on an earlier step's factor
    CHECK(r.iterations > 0);
}

TEST(reused_cholesky_step_meets_a_loose_tolerance) {
    // The user's tolerance is honoured as asked: at 1e-6 every At solve stops within it, Eq. 7's
    // residual stays within the bound that follows from it (above), and the run needs fewer
    // iterations than the same run to 1e-10 (it did stop early).
    const ReuseRun loose = reused_run(25, 40, 1e-6), tight = reused_run(25, 40, 1e-10);
    CHECK_LT(loose.worst_residual, 1e-6 * 1.0000001);
    CHECK_LT(loose.flesh_over_bound, 1.01);
    CHECK_LT(loose.handle_residual, 1e-9);
    CHECK_LT(tight.flesh_over_bound, 1.01);
    CHECK(loose.iterations < tight.iterations);
    CHECK(loose.stale_steps >= 10);
}

TEST(reused_cholesky_split_lanes_match_the_monolithic_step_on_one_thread_or_two) {
    // The world's hand solves b_t and the Schur columns as two groups of CG lanes, side by side
    // on two threads (HandSystem::beside, DeformableSystem::solve_many_split). Each step matches
    // the monolithic reference as the batched solve does, and two threads give the very same
    // steps as one; with an iteration limit of 1 the groups stop, the factor is renewed and every
    // column solved on it, still exact.
    const Beside sequential = [](const std::function<void()>& a, const std::function<void()>& b) {
        a();
        b();
    };
    const Beside threaded = [](const std::function<void()>& a, const std::function<void()>& b) {
        std::thread other(b);
        a();
        other.join();
    };
    for (int limit : {25, 1}) {
        const ReuseRun one = reused_run(limit, 20, 1e-10, sequential), two = reused_run(limit, 20, 1e-10, threaded);
        CHECK_LT(one.worst, 1e-8);
        CHECK_LT(one.worst_residual, 1e-10 * 1.0000001);
        CHECK(one.stale_steps >= 10);
        CHECK(one.x.size() == two.x.size() && (one.x - two.x).cwiseAbs().maxCoeff() == 0.0);
        CHECK(one.iterations == two.iterations && one.factorizations == two.factorizations);
        if (limit == 1) CHECK(one.factorizations >= 3);  // (renewed mid-step: the stale path ran)
    }
}

TEST(reused_cholesky_carried_and_fresh_response_solves_beside_b_t_are_the_plain_ones) {
    // The world's hand runs two more things on the Schur columns' side (HandSystem::beside):
    // the carried impulses' flesh pass (HandSystem::carried) and half the fresh response
    // columns' unit solves (DeformableSystem::response_blocks). On a second thread they give
    // bit for bit what the plain calls give one after the other: carried_response is
    // apply_inverse(carried, true) after the solve, also when the groups' stale path renews
    // the factor after the pass (iteration limit 1), and the unit columns (more than one
    // batch of them) are the same.
    const Beside threaded = [](const std::function<void()>& a, const std::function<void()>& b) {
        std::thread other(b);
        a();
        other.join();
    };
    const Beside sequential = [](const std::function<void()>& a, const std::function<void()>& b) {
        a();
        b();
    };
    const Model m = reused_box_model();
    const hh_params& p = m.params;
    for (int limit : {25, 1}) {
        Data beside(m), plain(m);
        beside.hand.beside = threaded;
        plain.hand.beside = sequential;  // (the same split of b_t and the Schur columns)
        int renewed_after_groups = 0;
        for (Data* d : {&beside, &plain}) {
            d->tool.reuse_iteration_limit = limit;
            d->device.enabled = true;
        }
        std::mt19937 rng(9);
        std::normal_distribution<double> g(0, 1);
        for (int s = 0; s < 10; ++s) {
            const double t = s * p.dt;
            const Eigen::Index n = 6 + 3 * m.mesh.n_nodes;
            VecX carried(n);
            for (Eigen::Index i = 0; i < n; ++i) carried[i] = 1e-3 * g(rng);
            std::vector<int> touched;  // 12 nodes' unknowns, a node more each step
            for (int k = 0; k < 12 + s; ++k)
                for (int d = 0; d < 3; ++d) touched.push_back(6 + 3 * ((5 * k + s) % m.mesh.n_nodes) + d);
            std::sort(touched.begin(), touched.end());
            touched.erase(std::unique(touched.begin(), touched.end()), touched.end());
            CHECK(touched.size() > static_cast<size_t>(kWidestSolve));
            MatX units[2];
            for (int which = 0; which < 2; ++which) {
                Data& d = which ? plain : beside;
                d.device.position = m.handle.rest_com + 0.03 * Vec3(std::sin(4 * t), 0.3 * t, 0);
                d.device.quaternion = quat_from_rotation_vector(Vec3(0, 0.5 * std::sin(3 * t), t));
                formulate(m, d);
                d.tool.reset_counters();
                if (which == 0) d.hand.carried = carried;
                d.hand.solve();
                if (which == 0) renewed_after_groups += d.tool.factorizations > 0 && d.tool.iterations > 0;
                CHECK(d.hand.apply_inverse_units(touched, touched, units[which]));
            }
            CHECK((beside.hand.s - plain.hand.s).cwiseAbs().maxCoeff() == 0.0);
            CHECK(beside.hand.carried.size() == 0);  // (used up)
            const VecX reference = plain.hand.apply_inverse(carried, true);
            CHECK((beside.hand.carried_response - reference).cwiseAbs().maxCoeff() == 0.0);
            CHECK((units[0] - units[1]).cwiseAbs().maxCoeff() == 0.0);
            integrate(m, beside, beside.hand.s);
            integrate(m, plain, plain.hand.s);
        }
        if (limit == 1) CHECK(renewed_after_groups >= 1);  // (the pass was solved again)
    }
}

TEST(reused_cholesky_stays_exact_across_forced_refactorizations) {
    // an iteration limit of 1: every stale solve that needs a second iteration renews the
    // factor on the spot and restarts from its iterate
    const ReuseRun r = reused_run(1, 25);
    CHECK_LT(r.worst, 1e-8);
    CHECK(r.factorizations >= 5);
}

TEST(reused_cholesky_warp_makes_a_rigidly_turned_hand_free) {
    // factor at rest, then turn the whole hand rigidly by 90 degrees: At becomes W At0 W^T with
    // W the rotation at every node, so the warped factor is exact and no refactorization is due
    const BoxMesh b = make_box(6, 4, 3, 0.01);
    hh_params p = box_params();
    p.solver = HH_SOLVER_REUSED_CHOLESKY;
    p.cg_tolerance = 1e-10;  // CG to round-off, to compare with the direct solves at 1e-8
    p.gravity[2] = 0;
    const Model m = build_model(b.nodes.data(), b.n_nodes(), b.tets.data(), b.n_tets(), p);
    Data d(m);
    std::mt19937 rng(5);
    std::normal_distribution<double> n(0, 1);
    for (int i = 0; i < d.v.size(); ++i) d.v[i] = 0.01 * n(rng);
    formulate(m, d);
    d.hand.solve();  // factors At0
    CHECK(d.tool.factorizations == 1);
    const Mat3 q = quat_to_matrix(quat_from_rotation_vector(Vec3(0, 0, 1.5707963267948966)));
    const Vec3 c = m.handle.rest_com;
    for (int i = 0; i < m.mesh.n_nodes; ++i) {
        d.x.segment<3>(3 * i) = c + q * (m.mesh.rest.segment<3>(3 * i) - c);
        d.v.segment<3>(3 * i) = q * d.v.segment<3>(3 * i);
    }
    d.h.q = quat_from_matrix(q);
    formulate(m, d);
    d.tool.reset_counters();
    d.hand.solve();
    const VecX mono = solve_monolithic(d.hand, d.hand.r);
    CHECK_LT((d.hand.s - mono).cwiseAbs().maxCoeff() / mono.cwiseAbs().maxCoeff(), 1e-8);
    CHECK(d.tool.factorizations == 0);
    CHECK(d.tool.iterations <= 2 * 7);  // 1 iteration per column in exact arithmetic
}

TEST(cholesky_schur_batched_solves_match_single_solves) {
    // the 7 batched solves and the combined 8th against one solve per right-hand side
    const BoxMesh b = make_box(4, 3, 2, 0.01);
    hh_params p = box_params();
    const Model m = build_model(b.nodes.data(), b.n_nodes(), b.tets.data(), b.n_tets(), p);
    Data d(m);
    solve_perturbed(m, d, 33);
    const Eigen::Index n3 = d.tool.A.rows();
    Eigen::SimplicialLDLT<SpMat> ref(d.tool.A);
    const VecX y0 = ref.solve(VecX(d.hand.r.tail(n3)));
    for (int i = 0; i < 6; ++i) {
        VecX col = VecX::Zero(n3);
        for (size_t j = 0; j < d.hand.coupled_nodes.size(); ++j) col.segment<3>(3 * d.hand.coupled_nodes[j]) = d.hand.Ath[j].col(i);
        const VecX t = ref.solve(col);
        CHECK_LT((d.hand.flesh_response().col(i) - t).norm() / t.norm(), 1e-12);
    }
    const Vec6 vh = d.hand.s.head<6>();
    VecX rhs = d.hand.r.tail(n3);
    for (size_t j = 0; j < d.hand.coupled_nodes.size(); ++j) rhs.segment<3>(3 * d.hand.coupled_nodes[j]) -= d.hand.Ath[j] * vh;
    const VecX vt = ref.solve(rhs);  // the pseudocode's 8th solve
    CHECK_LT((d.hand.s.tail(n3) - vt).norm() / vt.norm(), 1e-12);
    (void)y0;
}

TEST(hand_apply_inverse_many_on_chosen_rows_equals_the_full_solve) {
    // the contact solver asks only the rows it watches; they must be those of A^-1 rhs, for
    // handle rows (0-5) and flesh rows alike, with A^-1 checked against the monolithic solve
    SolvedBoxHand box(8);
    Data& d = box.d;
    const Eigen::Index n = d.hand.r.size();
    const MatX rhs = MatX::Random(n, 11);  // 11 columns: a full batch of 8 and a partial one
    MatX full, some;
    d.hand.apply_inverse_many(rhs, full);
    const std::vector<int> rows = {40, 2, 7, 0, static_cast<int>(n) - 1, 5, 19};
    d.hand.apply_inverse_many(rhs, some, &rows);
    CHECK(some.rows() == static_cast<Eigen::Index>(rows.size()) && some.cols() == rhs.cols());
    for (size_t i = 0; i < rows.size(); ++i)
        CHECK_LT((some.row(i) - full.row(rows[i])).cwiseAbs().maxCoeff(), 1e-12 * full.cwiseAbs().maxCoeff());
    const VecX mono = solve_monolithic(d.hand, rhs.col(3));
    CHECK_LT((full.col(3) - mono).cwiseAbs().maxCoeff(), 1e-8 * mono.cwiseAbs().maxCoeff());
    MatX units;  // a factor made every step keeps no columns: the contact build solves instead
    CHECK(!d.hand.apply_inverse_units({7, 8}, rows, units));
    // ... with unit columns straight at the rows (handle unknowns 0-5 among them): A^-1's
    // columns at those rows, checked against the full solve of the identity's columns
    const std::vector<int> unit_at = {7, 8, 0, 5, static_cast<int>(n) - 1, 19, 40, 12, 13, 3, 30};
    MatX e = MatX::Zero(n, static_cast<Eigen::Index>(unit_at.size()));
    for (size_t j = 0; j < unit_at.size(); ++j) e(unit_at[j], static_cast<Eigen::Index>(j)) = 1.0;
    MatX via_full, via_units = MatX::Constant(static_cast<Eigen::Index>(rows.size()), e.cols(), 7.0);
    d.hand.apply_inverse_many(e, via_full);
    // (the handle here is free, Aht is not zero: the handle's response to the units needs them prepared)
    bool refused = false;
    try {
        d.hand.apply_inverse_unit_columns(unit_at.data(), static_cast<int>(unit_at.size()), rows, via_units);
    } catch (const InvalidArgument&) {
        refused = true;
    }
    CHECK(refused);
    d.hand.prepare_unit_columns(unit_at);
    CHECK(d.hand.apply_inverse_unit_columns(unit_at.data(), static_cast<int>(unit_at.size()), rows, via_units));
    for (size_t i = 0; i < rows.size(); ++i)
        CHECK_LT((via_units.row(i) - via_full.row(rows[i])).cwiseAbs().maxCoeff(), 1e-12 * via_full.cwiseAbs().maxCoeff());
}

TEST(hand_handle_columns_are_the_flesh_solves_of_ath_and_aht_transposed) {
    // what the handle-space linearization reads: rows of A_t^-1 [Ath | aht^T] at chosen flesh
    // unknowns, against a separate sparse factorization of A_t; aht is any 6x3 block per
    // coupled node (the true one when the step zeroed the system's)
    SolvedBoxHand box(8);
    Data& d = box.d;
    const Eigen::Index n3 = d.tool.A.rows();
    std::vector<Mat63> aht(d.hand.coupled_nodes.size());
    for (Mat63& block : aht) block = Mat63::Random();
    MatX columns = MatX::Zero(n3, 12);
    for (size_t q = 0; q < aht.size(); ++q) {
        columns.block<3, 6>(3 * d.hand.coupled_nodes[q], 0) = d.hand.Ath[q];
        columns.block<3, 6>(3 * d.hand.coupled_nodes[q], 6) = aht[q].transpose();
    }
    Eigen::SimplicialLDLT<SpMat> ref(d.tool.A);
    const MatX expected = ref.solve(columns);
    const std::vector<int> unknowns = {6 + 40, 6 + 2, 6 + 7, static_cast<int>(n3) + 5, 6 + 19};
    MatX out;
    d.hand.handle_columns(unknowns, aht, out);
    CHECK(out.rows() == 5 && out.cols() == 12);
    for (size_t i = 0; i < unknowns.size(); ++i)
        CHECK_LT((out.row(i) - expected.row(unknowns[i] - 6)).cwiseAbs().maxCoeff(), 1e-10 * expected.cwiseAbs().maxCoeff());
}

TEST(hand_unit_columns_decline_a_tool_that_is_not_on_the_step_s_factor) {
    // apply_inverse_unit_columns solves only on the step's own Cholesky factor; with CG or the
    // reused factor it must say so (the contact build then solves as before) and leave out as it was
    for (int solver : {HH_SOLVER_CG, HH_SOLVER_REUSED_CHOLESKY}) {
        const BoxMesh b = make_box(4, 3, 2, 0.01);
        hh_params p = box_params();
        p.solver = solver;
        p.cg_tolerance = 1e-10;
        const Model m = build_model(b.nodes.data(), b.n_nodes(), b.tets.data(), b.n_tets(), p);
        Data d(m);
        solve_perturbed(m, d, 9);
        const std::vector<int> rows = {40, 2, 7}, units = {7, 40};
        MatX out = MatX::Constant(3, 2, 7.0);
        CHECK(!d.hand.apply_inverse_unit_columns(units.data(), 2, rows, out));
        CHECK(out.isConstant(7.0));
    }
}

TEST(reused_cholesky_measures_a_nearly_cancelled_load_against_its_reference_norm) {
    // The world's hand solves b_t plus the last step's contact impulses f, which at rest cancel
    // b_t to a few percent (World::solve_free). With b_t's norm as the reference, the flesh rows'
    // residual stays within tol (|b_t| + sum_i |v_h,i| |Ath_i|) (reused_run's bound, with |b_t| for
    // |b_t + f|), the reported residual is relative to the reference, fewer iterations are
    // needed than when measured against |b_t + f|, and the reference holds for one solve only.
    const double tol = 1e-8;
    struct Run {
        double over_bound = 0, reported = 0, next_over = 0;
        std::vector<int> iterations;  // per step
        int renewed = 0;               // the first step after the first that renewed the factor (0: none)
    };
    auto run = [&](bool with_reference) {
        const Model m = reused_box_model();
        Data d(m);
        d.tool.configure(DeformableSolver::ReusedCholesky, tol, 200);
        d.device.enabled = true;
        std::mt19937 rng(5);
        std::normal_distribution<double> n(0, 1);
        Run out;
        for (int s = 0; s < 20; ++s) {
            wave_device(m, d, s);
            formulate(m, d);
            const VecX r = d.hand.r;  // the step's own system, to integrate the same states in both runs
            const Eigen::Index n3 = d.tool.A.rows();
            const double bt = r.tail(n3).norm();
            // f: -b_t plus 3% of |b_t| in a random direction (odd steps: no reference, to check it lapsed)
            VecX xi(n3);
            for (Eigen::Index i = 0; i < n3; ++i) xi[i] = n(rng);
            const bool referenced = with_reference && s % 2 == 0;
            d.hand.r.tail(n3) = 0.03 * bt * xi / xi.norm();
            if (referenced) d.tool.set_reference_norm(0, bt);
            d.tool.reset_counters();
            d.hand.solve();
            out.iterations.push_back(d.tool.iterations);
            if (d.tool.factorizations > 0 && s > 0 && out.renewed == 0) out.renewed = s;
            // the flesh rows' residual of the solve (as in reused_run)
            const Vec6 vh = d.hand.s.head<6>();
            VecX flesh = d.tool.A * d.hand.s.tail(n3) - d.hand.r.tail(n3);
            double columns = 0;
            for (size_t j = 0; j < d.hand.coupled_nodes.size(); ++j)
                flesh.segment<3>(3 * d.hand.coupled_nodes[j]) += d.hand.Ath[j] * vh;
            for (int i = 0; i < 6; ++i) {
                VecX col = VecX::Zero(n3);
                for (size_t j = 0; j < d.hand.coupled_nodes.size(); ++j)
                    col.segment<3>(3 * d.hand.coupled_nodes[j]) = d.hand.Ath[j].col(i);
                columns += std::abs(vh[i]) * col.norm();
            }
            const double rhs = d.hand.r.tail(n3).norm();
            if (referenced) {
                out.over_bound = std::max(out.over_bound, flesh.norm() / (tol * (bt + columns)));
                out.reported = std::max(out.reported, d.tool.max_residual);
            } else {
                out.next_over = std::max(out.next_over, flesh.norm() / (tol * (rhs + columns)));
            }
            integrate(m, d, solve_monolithic(d.hand, r));
        }
        return out;
    };
    const Run with = run(true), without = run(false);
    CHECK_LT(with.over_bound, 1.01);
    CHECK_LT(with.reported, tol * 1.0000001);
    CHECK_LT(with.next_over, 1.01);     // the steps after a referenced one: measured against |b_t + f| again
    CHECK_LT(without.next_over, 1.01);
    CHECK(with.over_bound > 0.03);      // (the bound is not vacuous: the looser test was used)
    // Fewer iterations on the referenced steps, counted while both runs precondition with the
    // first step's factor: the renewal policy weighs each run's own costs, so after one run
    // renews its factor the two solve on different preconditioners.
    const int same_factor = std::min(with.renewed ? with.renewed : 20, without.renewed ? without.renewed : 20);
    int fewer = 0, more = 0;
    for (int s = 2; s < same_factor; s += 2) {
        fewer += with.iterations[s] < without.iterations[s];
        more += with.iterations[s] > without.iterations[s];
    }
    // (at least one referenced step compared: the policy prices a factorization by the
    // machine's kernels, so the first renewal comes at step 4 or 5 with AVX-512, later on AVX2)
    CHECK(same_factor > 2);
    CHECK(fewer > 0 && more == 0);
}

TEST(reused_cholesky_reference_norm_holds_for_one_solve_only) {
    // a reference a million times the right-hand side's norm lets the solve stop at once; the
    // next solve of the same slot, without one, is back to the tolerance relative to |b|
    const Model m = reused_box_model();
    Data d(m);
    d.device.enabled = true;
    d.device.position = m.handle.rest_com + Vec3(0.01, 0, 0);
    for (int s = 0; s < 3; ++s) {  // (a factor from the first step, reused by the next ones)
        formulate(m, d);
        d.hand.solve();
        integrate(m, d, d.hand.s);
    }
    formulate(m, d);
    const Eigen::Index n3 = d.tool.A.rows();
    std::mt19937 rng(9);
    std::normal_distribution<double> n(0, 1);
    MatX b(n3, 1), x;
    for (Eigen::Index i = 0; i < n3; ++i) b(i, 0) = n(rng);
    const double tol = m.params.cg_tolerance;
    d.tool.set_reference_norm(0, 1e6 * b.norm());
    d.tool.solve_many(b, x, 0);
    CHECK((d.tool.A * x - b).norm() > 1e3 * tol * b.norm());  // (stopped far from b's tolerance)
    d.tool.solve_many(b, x, 0);
    CHECK_LT((d.tool.A * x - b).norm(), 1.0000001 * tol * b.norm());
}

TEST(reused_cholesky_policy_counts_work_so_runs_repeat_exactly) {
    // the refactorization policy counts passes over the factor instead of timing them: two runs
    // of the same scenario factor at the same steps and end on identical states
    auto run = [](int limit, std::vector<int>& factored, VecX& x) {
        const Model m = reused_box_model();
        const hh_params& p = m.params;
        Data d(m);
        d.tool.reuse_iteration_limit = limit;
        d.device.enabled = true;
        for (int s = 0; s < 30; ++s) {
            wave_device(m, d, s);
            step(m, d, false);
            if (d.tool.factorizations > 0) factored.push_back(s);
        }
        x = d.x;
    };
    for (int limit : {25, 3}) {  // 3: renewals in the middle of solves too
        std::vector<int> f1, f2;
        VecX x1, x2;
        run(limit, f1, x1);
        run(limit, f2, x2);
        CHECK(f1 == f2);
        CHECK(!f1.empty() && f1[0] == 0);
        if (limit == 3) CHECK(f1.size() >= 2);
        CHECK((x1 - x2).cwiseAbs().maxCoeff() == 0.0);
    }
}

TEST(reused_cholesky_prices_the_kept_contact_responses_into_a_renewal) {
    // A renewal also makes the contact build solve again every response column kept since the
    // last one (response_units): with the responses of every flesh node kept each step, the same
    // motion renews its factor later than with none kept. Reading the kept columns changes no
    // solve, so both runs iterate alike until the first of them renews.
    auto first_renewal = [](bool keep) {
        const Model m = reused_box_model();
        Data d(m);
        d.device.enabled = true;
        std::vector<int> flesh(static_cast<size_t>(3 * m.mesh.n_nodes));
        for (size_t u = 0; u < flesh.size(); ++u) flesh[u] = static_cast<int>(u);
        MatX responses;
        for (int s = 0; s < 40; ++s) {
            wave_device(m, d, s);
            formulate(m, d);
            d.tool.reset_counters();
            d.hand.solve();
            if (s > 0 && d.tool.factorizations > 0) return s;
            if (keep) CHECK(d.tool.response_units(flesh, responses));
            integrate(m, d, d.hand.s);
        }
        return 40;
    };
    const int without = first_renewal(false), with = first_renewal(true);
    CHECK(without < 40);  // (the motion does call for a renewal)
    CHECK(with > without);
}

TEST(reused_cholesky_matches_a_fresh_factorization_every_step_on_a_larger_hand) {
    // a box big enough for wide supernodes (the dense-panel kernels and their 8-column groups)
    // and the single-precision passes: the reused-factor run against the per-step exact
    // factorization run, step by step, from the same states
    const BoxMesh b = make_box(8, 5, 4, 0.008);
    hh_params p = box_params();
    p.solver = HH_SOLVER_REUSED_CHOLESKY;
    p.cg_tolerance = 1e-10;  // CG to round-off, to compare with the direct solves at 1e-8
    const Model reused = build_model(b.nodes.data(), b.n_nodes(), b.tets.data(), b.n_tets(), p);
    p.solver = HH_SOLVER_CHOLESKY;
    const Model exact = build_model(b.nodes.data(), b.n_nodes(), b.tets.data(), b.n_tets(), p);
    Data dr(reused), de(exact);
    dr.device.enabled = de.device.enabled = true;
    double worst = 0;
    int stale = 0;
    for (int s = 0; s < 16; ++s) {
        const double t = s * p.dt;
        dr.device.position = de.device.position = reused.handle.rest_com + 0.04 * Vec3(std::sin(4 * t), 0.3 * t, 0);
        dr.device.quaternion = de.device.quaternion = quat_from_rotation_vector(Vec3(0, 0.5 * std::sin(3 * t), t));
        formulate(reused, dr);
        formulate(exact, de);
        dr.tool.reset_counters();
        dr.hand.solve();
        de.hand.solve();
        worst = std::max(worst, (dr.hand.s - de.hand.s).cwiseAbs().maxCoeff() / de.hand.s.cwiseAbs().maxCoeff());
        stale += dr.tool.iterations > 0;
        integrate(reused, dr, de.hand.s);  // both continue from the exact solution
        integrate(exact, de, de.hand.s);
    }
    CHECK_LT(worst, 1e-8);
    CHECK(stale >= 8);
}

TEST(reused_cholesky_contact_responses_use_one_operator_close_to_the_exact_inverse) {
    // With a lagged factor the contact responses come from the warped factor itself, not CG:
    // apply_inverse (the impulses' velocities) and apply_inverse_many (the Delassus operator)
    // must apply the same operator, so that the impulses solved with one are those the
    // velocities receive; with the factor of this very step they are the exact inverse. With the
    // handle free (Aht not zero: the unit columns need the flesh at the coupled nodes) and
    // prescribed (Aht zero: they do not, and are not asked for).
    const Model m = reused_box_model();
    const hh_params& p = m.params;
    for (bool prescribed : {false, true}) {
        Data d(m);
        d.device.enabled = true;
        d.device.prescribed = prescribed;
        int stale = 0;
        double cond = 0;  // of At (the single-precision pass's bound, below)
        for (int s = 0; s < 12; ++s) {
            const double t = s * p.dt;
            d.device.position = m.handle.rest_com + 0.03 * Vec3(std::sin(4 * t), 0.3 * t, 0);
            d.device.quaternion = quat_from_rotation_vector(Vec3(0, 0.5 * std::sin(3 * t), t));
            formulate(m, d);
            d.tool.reset_counters();
            d.hand.solve();
            const bool lagged = d.tool.iterations > 0;
            stale += lagged;
            const Eigen::Index n = d.hand.r.size();
            const MatX rhs = MatX::Random(n, 5);
            MatX many;
            d.hand.apply_inverse_many(rhs, many);
            const std::vector<int> rows = {0, 4, 9, static_cast<int>(n) - 2};
            MatX some;
            d.hand.apply_inverse_many(rhs, some, &rows);
            // the single-precision pass (the carried impulses, World::solve_free) applies the
            // inverse of a matrix within float round-off of the factor's: relative error about
            // cond(At) 2^-24 (cond of the first step's At, close to every step's here: a dense
            // eigensolve per step took minutes under the sanitizers)
            if (cond == 0) {
                const Eigen::SelfAdjointEigenSolver<MatX> eig{MatX(d.tool.A)};
                cond = eig.eigenvalues().maxCoeff() / eig.eigenvalues().minCoeff();
            }
            for (int j = 0; j < 5; ++j) {
                const VecX one = d.hand.apply_inverse(rhs.col(j));
                CHECK_LT((one - many.col(j)).cwiseAbs().maxCoeff(), 1e-12 * one.cwiseAbs().maxCoeff());
                const VecX single = d.hand.apply_inverse(rhs.col(j), true);
                CHECK_LT((single - one).norm(), 10 * cond * std::ldexp(1.0, -24) * one.norm());
                if (lagged) CHECK((single - one).norm() > 0);  // (it did take the single-precision copy)
                for (size_t i = 0; i < rows.size(); ++i) CHECK_LT(std::abs(some(i, j) - one[rows[i]]), 1e-12 * one.cwiseAbs().maxCoeff());
                if (lagged) continue;  // (an earlier matrix, warped: no exact bound to check)
                const VecX exact = solve_monolithic(d.hand, rhs.col(j));
                CHECK_LT((one - exact).cwiseAbs().maxCoeff(), 1e-8 * exact.cwiseAbs().maxCoeff());  // this step's factor
            }
            // unit columns from the kept response columns (the contact build's path): the same
            // operator again, on the first call of a step and on a second one served from the
            // columns kept (also across steps while the factor is not renewed)
            const std::vector<int> unknowns = {2, 6 + 3 * 5 + 1, 6 + 3 * 5 + 2, static_cast<int>(n) - 1, 6 + 3 * 11};
            MatX e = MatX::Zero(n, static_cast<Eigen::Index>(unknowns.size()));
            for (size_t j = 0; j < unknowns.size(); ++j) e(unknowns[j], j) = 1.0;
            MatX via_many, via_units;
            d.hand.apply_inverse_many(e, via_many, &rows);
            for (int call = 0; call < 2; ++call) {
                // (the second call with the baseline kernels: the handle's terms M_k have an
                // AVX2 form and a plain one)
                simd_level_override() = call == 0 ? -1 : 0;
                CHECK(d.hand.apply_inverse_units(unknowns, rows, via_units));
                CHECK_LT((via_units - via_many).cwiseAbs().maxCoeff(), 1e-12 * via_many.cwiseAbs().maxCoeff());
            }
            simd_level_override() = -1;
            // as the contact build asks (the touched unknowns at the touched rows), with nodes
            // joining from step to step: their columns are solved, their rows at the columns kept
            // from earlier steps come from symmetry
            std::vector<int> touched = {6 + 3 * 5 + 1, 6 + 3 * 5 + 2, 6 + 3 * 11};
            for (int q = 0; q <= s % 4; ++q) touched.push_back(6 + 3 * (13 + 2 * s + q) + q % 3);
            MatX et = MatX::Zero(n, static_cast<Eigen::Index>(touched.size()));
            for (size_t j = 0; j < touched.size(); ++j) et(touched[j], j) = 1.0;
            d.hand.apply_inverse_many(et, via_many, &touched);
            CHECK(d.hand.apply_inverse_units(touched, touched, via_units));
            CHECK_LT((via_units - via_many).cwiseAbs().maxCoeff(), 1e-12 * via_many.cwiseAbs().maxCoeff());
            // a soft body's path (World::ready_contact_body): the tool's own operator at the same
            // flesh unknowns, from the same kept blocks, is its solve_response of unit columns
            std::vector<int> flesh;
            for (int u : touched) flesh.push_back(u - 6);
            MatX ef = MatX::Zero(n - 6, static_cast<Eigen::Index>(flesh.size()));
            for (size_t j = 0; j < flesh.size(); ++j) ef(flesh[j], static_cast<Eigen::Index>(j)) = 1.0;
            MatX via_solve, via_tool_units;
            d.tool.solve_response(ef, via_solve);
            CHECK(d.tool.response_units(flesh, via_tool_units));
            // what the contact build weighs when it picks its basis (World::rows_cost_less): the
            // columns just served are kept, so none is solved afresh; a node never asked for
            // (flesh node 7: no row, unknown, touched or loaded node here) costs its three columns
            CHECK(d.tool.fresh_response_unknowns(flesh) == 0);
            CHECK(d.tool.fresh_response_unknowns({3 * 7 + 1, flesh[0]}) == 3);
            // the carried impulses' response at the touched unknowns (World::read_carried): f on
            // the touched nodes and on node 8 (never asked for before; its columns are solved
            // then and kept) is solve_response's P f there
            VecX f = VecX::Zero(n - 6);
            for (size_t j = 0; j < flesh.size(); ++j) f[flesh[j]] = 1.0 + 0.1 * static_cast<double>(j);
            f.segment<3>(3 * 8) = Vec3(0.3, -0.2, 0.5);
            VecX at;
            CHECK(d.tool.response_at(flesh, f, at));
            MatX whole;
            d.tool.solve_response(f, whole);
            double off = 0;
            for (size_t j = 0; j < flesh.size(); ++j) off = std::max(off, std::abs(at[static_cast<Eigen::Index>(j)] - whole(flesh[j], 0)));
            CHECK_LT(off, 1e-12 * whole.cwiseAbs().maxCoeff());
            CHECK(d.tool.fresh_response_unknowns({3 * 8}) == 0);
            double worst = 0, largest = 0;
            for (size_t r = 0; r < flesh.size(); ++r)
                for (size_t j = 0; j < flesh.size(); ++j) {
                    worst = std::max(worst, std::abs(via_tool_units(r, j) - via_solve(flesh[r], j)));
                    largest = std::max(largest, std::abs(via_solve(flesh[r], j)));
                }
            CHECK_LT(worst, 1e-12 * largest);
            bool aht_zero = true;  // (the step zeroes Aht for a prescribed handle)
            for (const Mat63& block : d.hand.Aht) aht_zero = aht_zero && block.isZero(0);
            CHECK(aht_zero == prescribed);
            integrate(m, d, d.hand.s);
        }
        CHECK(stale >= 4);
    }
}

// Issue 37, point 3: the step's rigid frame (sim/step_frame.h). Velocities that turn with the
// frame (each node's the frame's velocity at its turned position) carry every node and the
// handle to the frame's rigid motion exactly: no spring and no element is stretched by the turn.
TEST(a_velocity_field_turning_with_the_step_frame_moves_the_hand_rigidly) {
    const BoxMesh b = make_box(4, 3, 2, 0.01);
    const Model m = build_model(b.nodes.data(), b.n_nodes(), b.tets.data(), b.n_tets(), box_params());
    for (bool held : {false, true}) {
        Data d(m);
        const Vec3 omega(1.0, -2.0, 2.5);  // 3.4 rad/s: 0.11 rad per step
        for (int i = 0; i < m.mesh.n_nodes; ++i) d.v.segment<3>(3 * i) = omega.cross(d.x.segment<3>(3 * i) - d.h.x_com);
        d.h.omega = omega;
        d.device.enabled = held;
        d.device.position = d.h.x_com;
        formulate(m, d);
        const StepFrame f = d.frame;
        const VecX x0 = d.x;
        const Vec3 com0 = d.h.x_com;
        const Vec4 q0 = d.h.q;
        integrate(m, d, step_velocities(m, d, VecX::Zero(6 + 3 * m.mesh.n_nodes)));
        double error = 0;
        for (int i = 0; i < m.mesh.n_nodes; ++i) {
            const Vec3 rigid = f.center + f.rotation * (x0.segment<3>(3 * i) - f.center);
            error = std::max(error, (d.x.segment<3>(3 * i) - rigid).norm());
            error = std::max(error, (d.v.segment<3>(3 * i) - omega.cross(rigid - f.center)).norm() * m.params.dt);
        }
        error = std::max(error, (d.h.x_com - (f.center + f.rotation * (com0 - f.center))).norm());
        CHECK_LT(error, 1e-15);
        CHECK_LT((quat_to_matrix(d.h.q) - f.rotation * quat_to_matrix(q0)).cwiseAbs().maxCoeff(), 1e-14);
        // the springs' wrench is still zero: the handle's points turned with their nodes
        Vec3 force, torque;
        coupling_wrench(m, d, force, torque);
        CHECK_LT(force.norm() + torque.norm(), 1e-9);
    }
}
