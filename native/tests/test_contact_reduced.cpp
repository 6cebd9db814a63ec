// The reduced form of the contact problem (W = sum_b P_b C_b P_b^T, never formed) against the
// dense one: the same sweeps must give the same impulses, sweep for sweep.
#include <cstdlib>
#include <random>

#include "check.h"
#include "contact/pgs.h"

using namespace hh;

namespace {
// Two bodies sharing some contacts, many redundant contacts on few unknowns (as on an
// embedded surface): m_b unknowns per body, c contacts.
ReducedContactProblem random_problem(std::mt19937& rng, int c, int m0, int m1) {
    std::uniform_real_distribution<double> u(-1, 1);
    ReducedContactProblem p;
    p.dt = 1.0 / 30;
    for (int m : {m0, m1}) {
        MatX a = MatX::Random(m, m);
        p.bodies.push_back({a * a.transpose() / m + 0.05 * MatX::Identity(m, m)});
    }
    p.begin.assign(1, 0);
    p.u_free.resize(3 * c);
    p.gap.resize(c);
    p.friction.resize(c);
    p.kinetic.resize(c);
    for (int i = 0; i < c; ++i) {
        const int sides = i % 3 == 0 ? 2 : 1;  // a third of the contacts between the two bodies
        for (int s = 0; s < sides; ++s) {
            const int body = sides == 2 ? s : i % 2;
            const int m = body == 0 ? m0 : m1;
            for (int k = 0; k < 4; ++k) {
                const int index = static_cast<int>((u(rng) + 1) / 2 * (m - 1));
                p.entries.push_back({body, index, Vec3(u(rng), u(rng), u(rng)) * (s == 0 ? 1 : -1)});
            }
        }
        p.begin.push_back(static_cast<int>(p.entries.size()));
        p.u_free.segment<3>(3 * i) = Vec3(-0.2 + 0.1 * u(rng), 0.1 * u(rng), 0.1 * u(rng));
        p.gap[i] = 1e-4 * u(rng);
        p.friction[i] = 0.5;
        p.kinetic[i] = i % 4 == 0 ? 0.3 : 0.5;
    }
    return p;
}
}  // namespace

namespace {
// A soft element resting on a plane through many contacts, as the coarse bunny's ground
// contacts: one body, 4 nodes (12 unknowns), contact points at barycentric positions w_i of
// the element (rows w_iq along the frame per node), gaps affine in w (the distance of the
// point above the plane), a load pressing the element down and sideways (at `side` m/s).
ReducedContactProblem element_on_plane(std::mt19937& rng, int c, double side = 0.01) {
    std::uniform_real_distribution<double> u(0, 1);
    ReducedContactProblem p;
    p.dt = 1.0 / 30;
    // response of a soft element: SPD, strongly coupled nodes
    MatX a = MatX::Random(12, 12);
    p.bodies.push_back({a * a.transpose() / 12 + 0.02 * MatX::Identity(12, 12)});
    p.begin.assign(1, 0);
    p.u_free.resize(3 * c);
    p.gap.resize(c);
    p.friction = VecX::Constant(c, 0.6);
    p.kinetic = VecX::Constant(c, 0.6);
    const Vec4 height(0, 1e-4, 3e-4, 2e-3);             // nodal heights above the contact layer
    const Vec3 v_node[4] = {Vec3(side, 0, -0.05), Vec3(side, 0.002, -0.06), Vec3(1.2 * side, 0, -0.04), Vec3(0, 0, -0.05)};
    for (int i = 0; i < c; ++i) {
        // points near the bottom face (nodes 0-2), a few above it
        Vec4 w(u(rng), u(rng), u(rng), i % 5 == 0 ? 0.2 * u(rng) : 0.0);
        w /= w.sum();
        Vec3 v = Vec3::Zero();
        for (int q = 0; q < 4; ++q) {
            for (int d = 0; d < 3; ++d) p.entries.push_back({0, 3 * q + d, w[q] * Vec3::Unit(d)});
            v += w[q] * v_node[q];
        }
        p.begin.push_back(static_cast<int>(p.entries.size()));
        // frame: normal z, tangents x, y
        p.u_free.segment<3>(3 * i) = Vec3(v.z(), v.x(), v.y());
        p.gap[i] = w.dot(height);
    }
    return p;
}

// `elements` of those elements on the plane as one problem (each element a body of its own),
// `per` contacts each: with 8 x 60, far more active contacts than the subspace step takes.
ReducedContactProblem elements_on_plane(std::mt19937& rng, int elements, int per) {
    ReducedContactProblem p;
    p.dt = 1.0 / 30;
    p.begin.assign(1, 0);
    for (int k = 0; k < elements; ++k) {
        const ReducedContactProblem e = element_on_plane(rng, per);
        p.bodies.push_back(e.bodies[0]);
        for (int i = 0; i < per; ++i) {
            for (int j = e.begin[i]; j < e.begin[i + 1]; ++j) p.entries.push_back({k, e.entries[j].index, e.entries[j].coefficient});
            p.begin.push_back(static_cast<int>(p.entries.size()));
        }
        p.u_free.conservativeResize(3 * per * (k + 1));
        p.u_free.tail(3 * per) = e.u_free;
        for (const VecX* from : {&e.gap, &e.friction, &e.kinetic}) {
            VecX& to = from == &e.gap ? p.gap : (from == &e.friction ? p.friction : p.kinetic);
            to.conservativeResize(per * (k + 1));
            to.tail(per) = *from;
        }
    }
    return p;
}

// Every condition of the contact problem, checked on the dense W independently of the solver.
double dense_residual(const ReducedContactProblem& p, const MatX& w, const VecX& lambda) {
    const VecX u = p.u_free + w * lambda;
    double worst = 0;
    for (int i = 0; i < static_cast<int>(p.gap.size()); ++i) {
        const double un = u[3 * i] + std::max(p.gap[i] / p.dt, -p.recovery_speed);
        worst = std::max(worst, lambda[3 * i] > 0 ? std::abs(un) : std::max(0.0, -un));
        const Eigen::Vector2d ut = u.segment<2>(3 * i + 1), lt = lambda.segment<2>(3 * i + 1);
        const double limit = p.friction[i] * lambda[3 * i];
        if (!(limit > 0)) continue;
        worst = std::max(worst, lt.norm() < limit * (1 - 1e-9) ? ut.norm() : (ut + ut.norm() / lt.norm() * lt).norm());
    }
    return worst;
}
double dense_residual(const ReducedContactProblem& p, const VecX& lambda) { return dense_residual(p, p.delassus(), lambda); }

// Plain projected Gauss-Seidel on the dense W, written apart from pgs.cpp (no subspace steps,
// the friction disk by bisection on the multiplier), run until no impulse changes by more than
// `change`: the reference the solver's results are compared with.
VecX reference_pgs(const ReducedContactProblem& p, const MatX& w, int sweeps, double change) {
    const int c = static_cast<int>(p.gap.size());
    VecX lambda = VecX::Zero(3 * c);
    VecX u = p.u_free;
    for (int s = 0; s < sweeps; ++s) {
        double moved = 0;
        for (int i = 0; i < c; ++i) {
            const Mat3 b = w.block<3, 3>(3 * i, 3 * i);
            const double bias = std::max(p.gap[i] / p.dt, -p.recovery_speed);
            const Vec3 old = lambda.segment<3>(3 * i);
            const double ln = std::max(0.0, old[0] - (u[3 * i] + bias) / b(0, 0));
            u += w.col(3 * i) * (ln - old[0]);
            // friction: argmin over |x| <= mu ln of 1/2 x^T B x - g^T x (B the tangential block)
            const Eigen::Matrix2d bt = b.block<2, 2>(1, 1);
            const Eigen::Vector2d g = bt * old.tail<2>() - u.segment<2>(3 * i + 1);
            auto at = [&](double nu) { return Eigen::Vector2d((bt + nu * Eigen::Matrix2d::Identity()).ldlt().solve(g)); };
            const double r = p.friction[i] * ln;
            Eigen::Vector2d x = r > 0 ? at(0) : Eigen::Vector2d::Zero();
            if (x.norm() > r) {
                double lo = 0, hi = 1;
                while (at(hi).norm() > r) hi *= 2;
                for (int k = 0; k < 200; ++k) (at(0.5 * (lo + hi)).norm() > r ? lo : hi) = 0.5 * (lo + hi);
                x = at(hi);
            }
            u += w.middleCols<2>(3 * i + 1) * (x - old.tail<2>());
            lambda.segment<3>(3 * i) = Vec3(ln, x[0], x[1]);
            moved = std::max(moved, (lambda.segment<3>(3 * i) - old).cwiseAbs().maxCoeff());
        }
        if (moved < change) break;
    }
    return lambda;
}
}  // namespace


TEST(reduced_sweeps_equal_dense_sweeps) {
    std::mt19937 rng(7);
    for (int trial = 0; trial < 5; ++trial) {
        const ReducedContactProblem r = random_problem(rng, 60, 12, 18);
        ContactProblem d;
        d.W = r.delassus();
        CHECK_LT((d.W - d.W.transpose()).cwiseAbs().maxCoeff(), 1e-12);
        d.u_free = r.u_free;
        d.gap = r.gap;
        d.friction = r.friction;
        d.kinetic = r.kinetic;
        d.dt = r.dt;
        for (int cap : {1, 7, 200}) {
            VecX lr, ld;
            const PgsResult a = solve_pgs(r, lr, cap, 1e-9);
            const PgsResult b = solve_pgs(d, ld, cap, 1e-9);
            CHECK(a.iterations == b.iterations);
            CHECK_LT((lr - ld).cwiseAbs().maxCoeff(), 1e-9 * (1 + ld.cwiseAbs().maxCoeff()));
            CHECK_LT(std::abs(a.residual - b.residual), 1e-9);
            // the impulses satisfy the cone
            for (int i = 0; i < 60; ++i) {
                CHECK(lr[3 * i] >= 0);
                CHECK(std::hypot(lr[3 * i + 1], lr[3 * i + 2]) <= r.friction[i] * lr[3 * i] * (1 + 1e-12) + 1e-15);
            }
        }
    }
}

TEST(a_contact_without_normal_impulse_may_slide) {
    // one contact opening (u_n > 0 after any impulse) while sliding: no impulse, and the
    // residual does not ask it to stick, so the solve ends at once
    ReducedContactProblem p;
    p.dt = 0.01;
    p.bodies.push_back({Mat3::Identity()});
    p.begin = {0, 3};
    for (int d = 0; d < 3; ++d) p.entries.push_back({0, d, Vec3::Unit(d)});
    p.u_free = Vec3(0.1, 0.3, 0);
    p.gap = VecX::Constant(1, 0.0);
    p.friction = VecX::Constant(1, 0.5);
    p.kinetic = VecX::Constant(1, 0.5);
    VecX lambda;
    const PgsResult res = solve_pgs(p, lambda, 300, 1e-9);
    CHECK(res.iterations == 1);
    CHECK_LT(lambda.cwiseAbs().maxCoeff(), 1e-15);
    CHECK_LT(res.residual, 1e-15);
}

TEST(nearly_dependent_contacts_are_solved_by_the_subspace_step) {
    // Two frictionless contacts whose normal rows are 0.05 rad apart on a unit response
    // (W_nn = [[1, c], [c, 1]], c = cos 0.05): Gauss-Seidel reduces the residual by c^2 per
    // sweep, ~7000 sweeps to 1e-9. A third contact exactly dependent on them (the mean of their
    // rows, and a consistent free velocity) makes the system singular. The subspace steps
    // solve the active set: the one at sweep 10, damped by 1e-4 of the diagonal, removes
    // 1 - 1e-4 / (1 - c + 1e-4) = 93% of the error along the rows' weak combination (stiffness
    // 1 - c = 1.25e-3), the one at sweep 20, damped by 1e-5, 99% of the rest; the impulses are
    // then the solution lambda = -W^-1 u_free of the two independent rows, with the dependent
    // contact's impulse shared between them.
    const double theta = 0.05, c = std::cos(theta);
    ReducedContactProblem p;
    p.dt = 0.01;
    p.bodies.push_back({MatX::Identity(8, 8)});
    p.begin.assign(1, 0);
    const Eigen::Matrix<double, 8, 1> n1 = Eigen::Matrix<double, 8, 1>::Unit(0);
    const Eigen::Matrix<double, 8, 1> n2 = c * n1 + std::sin(theta) * Eigen::Matrix<double, 8, 1>::Unit(1);
    const Eigen::Matrix<double, 8, 1> normal[3] = {n1, n2, 0.5 * (n1 + n2)};
    for (int i = 0; i < 3; ++i) {
        for (int k = 0; k < 8; ++k) {
            Vec3 coefficient(normal[i][k], 0, 0);
            if (k == 2 + 2 * i) coefficient[1] = 1;  // tangents on unknowns of their own
            if (k == 3 + 2 * i) coefficient[2] = 1;
            if (coefficient.squaredNorm() > 0) p.entries.push_back({0, k, coefficient});
        }
        p.begin.push_back(static_cast<int>(p.entries.size()));
    }
    p.u_free = VecX::Zero(9);
    p.u_free[0] = -0.1;
    p.u_free[3] = -0.1001;
    p.u_free[6] = 0.5 * (p.u_free[0] + p.u_free[3]);
    p.gap = VecX::Zero(3);
    p.friction = VecX::Zero(3);
    p.kinetic = VecX::Zero(3);
    VecX lambda;
    const PgsResult res = solve_pgs(p, lambda, 300, 1e-9);
    CHECK(res.residual <= 1e-9);
    CHECK(res.iterations <= 30);
    // exact: [[1, c], [c, 1]] l = (0.1, 0.1001), with the dependent contact's share folded in
    // (its row is the mean of the two: lambda_1 + lambda_3 / 2 and lambda_2 + lambda_3 / 2)
    const double l1 = (0.1 - c * 0.1001) / (1 - c * c), l2 = (0.1001 - c * 0.1) / (1 - c * c);
    CHECK(l1 > 0 && l2 > 0);
    // the residual (at most 1e-9 per contact) bounds the error of the folded impulses through
    // the smallest eigenvalue of [[1, c], [c, 1]], 1 - c: 1.1e-6, 1e-4 of l1 and l2 (~1e-2)
    const double bound = std::sqrt(2.0) * 1e-9 / (1 - c);
    CHECK_LT(std::abs(lambda[0] + 0.5 * lambda[6] - l1), bound);
    CHECK_LT(std::abs(lambda[3] + 0.5 * lambda[6] - l2), bound);
    CHECK_LT(dense_residual(p, lambda), 1e-8);
}

TEST(redundant_contacts_on_one_element_converge) {
    // 60 contacts on 4 nodes (rank of the rows <= 12 against 180): Gauss-Seidel alone crawls
    // along the nearly dependent rows; with the subspace steps the solve meets the tolerance
    // well within the cap, and the conditions hold on the dense W, not only by the solver's
    // own count.
    std::mt19937 rng(11);
    for (int trial = 0; trial < 4; ++trial) {
        const ReducedContactProblem p = element_on_plane(rng, 60);
        VecX lambda;
        const PgsResult res = solve_pgs(p, lambda, 300, 1e-6);
        CHECK(res.residual <= 1e-6);
        CHECK(res.iterations < 150);
        CHECK_LT(dense_residual(p, lambda), 2e-6);
        for (int i = 0; i < 60; ++i) {
            CHECK(lambda[3 * i] >= 0);
            CHECK(std::hypot(lambda[3 * i + 1], lambda[3 * i + 2]) <= p.friction[i] * lambda[3 * i] * (1 + 1e-12) + 1e-15);
        }
        // the element is held: its total normal impulse stops the downward free velocity
        // (every node comes to rest on the layer or above it)
        double total = 0;
        for (int i = 0; i < 60; ++i) total += lambda[3 * i];
        CHECK(total > 0);
    }
}

TEST(sliding_contacts_keep_their_friction_on_the_rim_in_the_subspace_step) {
    // The element of the test above dragged sideways at 0.5 m/s: every contact that pushes slides,
    // its friction mu lambda_n against the sliding. The subspace step must move a sliding
    // contact's friction with its normal impulse (lambda_t = mu lambda_n d): when it kept the
    // friction impulse while lowering lambda_n, the friction ended outside the disk, was cut
    // back to the rim, the velocities no longer solved the step's equations and the step was
    // rejected; the former step took 14 sweeps to the cap of 300 on these problems. Now each
    // meets the tolerance within 40 sweeps, on the dense W too.
    std::mt19937 rng(11);
    for (int trial = 0; trial < 4; ++trial) {
        const ReducedContactProblem p = element_on_plane(rng, 60, 0.5);
        VecX lambda;
        const PgsResult res = solve_pgs(p, lambda, 300, 1e-6);
        CHECK(res.residual <= 1e-6);
        CHECK(res.iterations <= 40);
        CHECK_LT(dense_residual(p, lambda), 2e-6);
        double normal = 0, along = 0;
        for (int i = 0; i < 60; ++i) {
            CHECK(lambda[3 * i] >= 0);
            const double lt = std::hypot(lambda[3 * i + 1], lambda[3 * i + 2]);
            CHECK(lt <= p.friction[i] * lambda[3 * i] * (1 + 1e-12) + 1e-15);
            normal += lambda[3 * i];
            along += lambda[3 * i + 1];
        }
        // the drag is along tangent 1 (+x): friction holds it back, at most mu times the load
        CHECK(normal > 0);
        CHECK(along < 0);
        CHECK(-along <= 0.6 * normal * (1 + 1e-9));
    }
}

TEST(frictionless_redundant_contacts_match_plain_gauss_seidel) {
    // Without friction the problem is a convex QP in lambda (min 1/2 l^T W l + b^T l, l_n >= 0),
    // whose velocities u = u_free + W l are unique even where the impulses are not (40 contacts
    // on 12 unknowns). The solver with its subspace steps (a basic solution: dependent contacts
    // take no impulse) and plain Gauss-Seidel run to convergence must give the same u.
    std::mt19937 rng(5);
    for (int trial = 0; trial < 3; ++trial) {
        ReducedContactProblem p = element_on_plane(rng, 40);
        p.friction.setZero();
        p.kinetic.setZero();
        VecX lambda;
        const PgsResult res = solve_pgs(p, lambda, 300, 1e-9);
        CHECK(res.residual <= 1e-9);
        const MatX w = p.delassus();
        const VecX reference = reference_pgs(p, w, 100000, 1e-14);
        CHECK_LT(dense_residual(p, w, reference), 1e-9);
        const VecX u = p.u_free + w * lambda, u_ref = p.u_free + w * reference;
        CHECK_LT((u - u_ref).cwiseAbs().maxCoeff(), 1e-8);
    }
}

TEST(an_open_contact_left_out_of_the_sweeps_is_taken_back_when_it_closes) {
    // The sweeps leave out contacts without impulse that are open by more than the tolerance,
    // visiting every contact again every 10 sweeps and after a subspace step. Contacts 1 and 2
    // are the nearly dependent pair of the test above (theta = 0.05); contact 3 is open (u_n =
    // 2 mm/s) and its row leans against contact 2's (W_32 = -sin theta): while Gauss-Seidel
    // crawls, contact 2's impulse stays small and contact 3 stays open, so it is left out; the
    // subspace step then gives contact 2 its full impulse, which closes contact 3. The solve must
    // still end with every condition met, contact 3 pushing, and the velocities of plain
    // Gauss-Seidel run to convergence (frictionless: u is unique).
    const double theta = 0.05, c = std::cos(theta);
    using V8 = Eigen::Matrix<double, 8, 1>;
    ReducedContactProblem p;
    p.dt = 0.01;
    p.bodies.push_back({MatX::Identity(8, 8)});
    p.begin.assign(1, 0);
    const V8 normal[3] = {V8::Unit(0), c * V8::Unit(0) + std::sin(theta) * V8::Unit(1), V8::Unit(2) - V8::Unit(1)};
    for (int i = 0; i < 3; ++i) {
        for (int k = 0; k < 8; ++k)
            if (normal[i][k] != 0) p.entries.push_back({0, k, Vec3(normal[i][k], 0, 0)});
        p.begin.push_back(static_cast<int>(p.entries.size()));
    }
    p.u_free = VecX::Zero(9);
    p.u_free[0] = -0.1;
    p.u_free[3] = -0.1001;
    p.u_free[6] = 0.002;
    p.gap = VecX::Zero(3);
    p.friction = VecX::Zero(3);
    p.kinetic = VecX::Zero(3);
    const MatX w = p.delassus();
    {
        // after the first sweep contact 3 has no impulse and is open: it is left out
        VecX lambda;
        solve_pgs(p, lambda, 1, 1e-9);
        CHECK(lambda[6] == 0);
        CHECK(p.u_free[6] + w.row(6).dot(lambda) > 1e-3);
    }
    VecX lambda;
    const PgsResult res = solve_pgs(p, lambda, 300, 1e-9);
    CHECK(res.residual <= 1e-9);
    CHECK(res.iterations < 300);
    CHECK_LT(dense_residual(p, w, lambda), 1e-9);
    CHECK(lambda[6] > 1e-3);  // contact 3 closed and pushes
    const VecX reference = reference_pgs(p, w, 100000, 1e-14);
    CHECK(reference[6] > 1e-3);
    CHECK_LT(((w * lambda) - (w * reference)).cwiseAbs().maxCoeff(), 1e-8);
}

TEST(single_precision_response_columns_change_the_solution_by_round_off_only) {
    // Large problems sweep with single-precision copies of the response columns (memory
    // traffic); the velocities stay double and are recomputed exactly every full sweep. On the
    // redundant element-on-plane problems the impulses must meet every condition on the exact
    // (double) W as the double sweeps' do (the bound of redundant_contacts_on_one_element_
    // converge: float round-off of the velocity changes, ~1e-7 of |u| ~ 0.06 m/s, is far below).
    std::srand(11);  // (element_on_plane's responses come from Eigen's Random, i.e. rand())
    std::mt19937 rng(11);
    for (int trial = 0; trial < 4; ++trial) {
        ReducedContactProblem p = element_on_plane(rng, 60);
        VecX ld, ls;
        p.single_columns = 0;
        const PgsResult a = solve_pgs(p, ld, 5000, 1e-6);
        p.single_columns = 1;
        const PgsResult b = solve_pgs(p, ls, 5000, 1e-6);
        CHECK(a.residual <= 1e-6 && b.residual <= 1e-6);
        CHECK_LT(dense_residual(p, ld), 2e-6);
        CHECK_LT(dense_residual(p, ls), 2e-6);
        double total_d = 0, total_s = 0;  // the element is held by the same total impulse
        for (int i = 0; i < 60; ++i) {
            CHECK(ls[3 * i] >= 0);
            total_d += ld[3 * i];
            total_s += ls[3 * i];
        }
        CHECK_LT(std::abs(total_s - total_d), 1e-3 * total_d);
    }
}

TEST(large_problems_leave_settled_contacts_out_and_still_meet_every_condition) {
    // Over 64 active contacts the subspace step cannot run; the sweeps then leave settled
    // contacts out and keep only the entries of y the others read, catching the rest up at
    // each full sweep. That bookkeeping must be exact: the solver's residual agrees with the
    // conditions on the dense W, in double and in single-precision columns. (Not compared with
    // each element solved alone: with Coulomb friction the impulses need not be unique, and
    // the joint and separate solves, old sweeps and new, hold some elements differently.)
    std::srand(7);
    std::mt19937 rng(7);
    const int elements = 8, per = 60;
    ReducedContactProblem p = elements_on_plane(rng, elements, per);
    for (int columns : {0, 1}) {
        p.single_columns = columns;
        VecX lambda;
        const PgsResult res = solve_pgs(p, lambda, 20000, 1e-6);
        int active = 0;
        for (int i = 0; i < elements * per; ++i) active += lambda[3 * i] > 0;
        CHECK(active > 64);
        CHECK(res.residual <= 1e-6);
        CHECK_LT(dense_residual(p, lambda), 2e-6);
        for (int i = 0; i < elements * per; ++i) {
            CHECK(lambda[3 * i] >= 0);
            CHECK(std::hypot(lambda[3 * i + 1], lambda[3 * i + 2]) <= p.friction[i] * lambda[3 * i] * (1 + 1e-12) + 1e-15);
        }
    }
}

TEST(columns_formed_as_the_sweeps_need_them_give_the_same_impulses) {
    // The world forms up front only the columns of contacts its warm start gives an impulse; the
    // sweeps form the others' when they first change them (ReducedColumns::ensure) and leave
    // contacts without columns that stay open untouched. That must change nothing: the
    // impulses, bit for bit, as with every contact's columns formed up front, on a problem
    // small enough for the subspace step (two bodies) and on one too large for it (eight
    // elements), in double and single-precision columns.
    std::srand(5);
    std::mt19937 rng(5);
    std::vector<ReducedContactProblem> problems;
    problems.push_back(random_problem(rng, 90, 40, 30));
    {
        ReducedContactProblem p;  // eight elements on a plane, as one problem
        p.dt = 1.0 / 30;
        p.begin.assign(1, 0);
        for (int k = 0; k < 8; ++k) {
            const ReducedContactProblem e = element_on_plane(rng, 60);
            p.bodies.push_back(e.bodies[0]);
            for (int i = 0; i < 60; ++i) {
                for (int j = e.begin[i]; j < e.begin[i + 1]; ++j) p.entries.push_back({k, e.entries[j].index, e.entries[j].coefficient});
                p.begin.push_back(static_cast<int>(p.entries.size()));
            }
            for (auto [from, to] : {std::pair<const VecX*, VecX*>{&e.u_free, &p.u_free}, {&e.gap, &p.gap}, {&e.friction, &p.friction},
                                    {&e.kinetic, &p.kinetic}}) {
                to->conservativeResize(to->size() + from->size());
                to->tail(from->size()) = *from;
            }
        }
        problems.push_back(p);
    }
    for (ReducedContactProblem& p : problems) {
        const int c = static_cast<int>(p.gap.size());
        for (int columns : {0, 1}) {
            p.single_columns = columns;
            // a warm start as the world's: some contacts pushing, the others without impulse
            VecX warm;
            solve_pgs(p, warm, 15, 1e-9);
            for (int i = 0; i < c; i += 3) warm.segment<3>(3 * i).setZero();
            int pushing = 0;
            for (int i = 0; i < c; ++i) pushing += warm.segment<3>(3 * i) != Vec3::Zero();
            CHECK(pushing > 0 && pushing < c);
            ReducedColumns all(p);
            all.form(0, 1);
            VecX la = warm;
            const PgsResult ra = solve_pgs(p, all, la, 400, 1e-7);
            ReducedColumns needed(p, &warm);
            needed.form(0, 2);  // (in two shares, as the world's)
            needed.form(1, 2);
            CHECK(needed.formed_count() == pushing);
            VecX lb = warm;
            const PgsResult rb = solve_pgs(p, needed, lb, 400, 1e-7);
            CHECK(needed.formed_count() > pushing);  // some formed by the sweeps...
            CHECK(needed.formed_count() < c);        // ... and some never needed
            CHECK(ra.iterations == rb.iterations);
            CHECK(ra.residual == rb.residual);
            CHECK(la == lb);
        }
    }
}

TEST(sweeps_that_stall_near_the_tolerance_end_early_within_the_factor) {
    // The eight elements of the test above (too many active contacts for the subspace step)
    // crawl near the tolerance. Reference: no stall stop and a cap far beyond need.
    std::mt19937 rng(7);
    const ReducedContactProblem p = elements_on_plane(rng, 8, 60);
    const double tolerance = 1e-6, factor = 4;
    const MatX w = p.delassus();
    VecX reference;
    const PgsResult converged = solve_pgs(p, reference, 20000, tolerance);
    CHECK(converged.residual <= tolerance);
    // With the stall stop and that cap, the sweeps' rate brings the tolerance within reach:
    // nothing changes.
    VecX lambda;
    PgsResult res = solve_pgs(p, lambda, 20000, tolerance, factor);
    CHECK(res.iterations == converged.iterations);
    CHECK((lambda - reference).cwiseAbs().maxCoeff() == 0);
    // A cap that does not leave room for the tolerance: three quarters of the sweeps it takes.
    const int cap = 3 * converged.iterations / 4;
    // without the stall stop: on to the cap, above the tolerance
    VecX plain;
    const PgsResult capped = solve_pgs(p, plain, cap, tolerance);
    CHECK(capped.iterations == cap);
    CHECK(capped.residual > tolerance);
    CHECK(capped.residual <= factor * tolerance);  // (so the stall stop may act before the cap)
    // with it: an earlier end, within the factor of the tolerance by the solver's count and on
    // the dense W
    lambda.resize(0);
    res = solve_pgs(p, lambda, cap, tolerance, factor);
    CHECK(res.iterations < cap);
    CHECK(res.residual <= factor * tolerance);
    CHECK_LT(dense_residual(p, w, lambda), factor * tolerance * (1 + 1e-6));
    for (int i = 0; i < 480; ++i) {
        CHECK(lambda[3 * i] >= 0);
        CHECK(std::hypot(lambda[3 * i + 1], lambda[3 * i + 2]) <= p.friction[i] * lambda[3 * i] * (1 + 1e-12) + 1e-15);
    }
}
