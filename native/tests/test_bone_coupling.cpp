// The bones' handle-space model with contacts held (haptics/bone_coupling_model.h; docs/skeleton.md,
// Section 6) against the palm handle's (haptics/coupling_model.h) on a one-bone hand, and its
// two ways of forming H_l against each other on three bones pressed on the ground. (That it is
// the derivative of the world's step: tests/engine/test_skeleton_linearization.py.)
#include <string>
#include <vector>

#include "box_mesh.h"
#include "capi/guard.h"
#include "check.h"
#include "haptic_hand.h"
#include "haptics/bone_coupling_model.h"
#include "rigid/quaternion.h"

using namespace hh;

namespace {
double relative(const MatX& a, const MatX& b) { return (a - b).cwiseAbs().maxCoeff() / b.cwiseAbs().maxCoeff(); }

// A world with the box hand (every node a surface vertex, its bottom face's triangles) on a
// plane 1.5 mm below it, friction 0.5, gravity on, two threads.
struct PressedBox {
    BoxMesh box;
    hh_model* model = nullptr;
    hh_world* world = nullptr;
    int hand = -1;
    PressedBox(int nx, int ny, int nz, const std::vector<BoneDesc>* bones, const hh_params& p) : box(make_box(nx, ny, nz, 0.01)) {
        if (bones) {
            std::vector<int> parents;
            std::vector<double> heads, tails, radii;
            for (const BoneDesc& b : *bones) {
                parents.push_back(b.parent);
                heads.insert(heads.end(), b.head.data(), b.head.data() + 3);
                tails.insert(tails.end(), b.tail.data(), b.tail.data() + 3);
                radii.push_back(b.radius);
            }
            hh_skeleton_desc s{static_cast<int>(sizeof(hh_skeleton_desc)), static_cast<int>(bones->size()), parents.data(),
                               heads.data(), tails.data(), radii.data(), nullptr, nullptr, nullptr, nullptr};
            CHECK(hh_model_create_skeleton(box.nodes.data(), box.n_nodes(), box.tets.data(), box.n_tets(), &p, &s, &model) ==
                  HH_OK);
        } else {
            CHECK(hh_model_create(box.nodes.data(), box.n_nodes(), box.tets.data(), box.n_tets(), &p, &model) == HH_OK);
        }
        hh_world_params wp;
        hh_default_world_params(&wp);
        wp.tolerance = 1e-12;
        wp.max_iterations = 100000;
        wp.stall_factor = 0;
        CHECK(hh_world_create(&wp, &world) == HH_OK);
        std::vector<int> nodes(4 * box.n_nodes(), 0), faces;
        std::vector<double> weights(4 * box.n_nodes(), 0.0);
        for (int i = 0; i < box.n_nodes(); ++i) {
            nodes[4 * i] = i;
            weights[4 * i] = 1;
        }
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) {
                const int a = j * (nx + 1) + i, b = a + 1, c = a + nx + 1, d = c + 1;
                faces.insert(faces.end(), {a, c, b, b, c, d});
            }
        CHECK(hh_world_add_hand(world, model, nodes.data(), weights.data(), box.n_nodes(), faces.data(),
                                static_cast<int>(faces.size() / 3), 0.5, 0, &hand) == HH_OK);
        const double ground[3] = {0, 0, -0.0015}, up[3] = {0, 0, 1};
        int plane = -1;
        CHECK(hh_world_add_plane(world, ground, up, 0.5, &plane) == HH_OK);
    }
    ~PressedBox() {
        hh_world_free(world);
        hh_model_free(model);
    }
    // every bone prescribed k mm down from where it is, turned about the vertical by k * 0.02 rad
    void press(int steps) {
        const int nb = world->w.bodies[hand]->hand_model->n_bones();
        std::vector<double> p(3 * nb), q(4 * nb);
        CHECK(hh_world_bone_states(world, hand, nb, p.data(), q.data(), nullptr) == HH_OK);
        std::vector<int> modes(nb, HH_BONE_PRESCRIBED);
        for (int k = 1; k <= steps; ++k) {
            std::vector<double> pk = p, qk(4 * nb);
            const Vec4 turn = quat_from_rotation_vector(Vec3(0, 0, 0.02 * k));
            for (int b = 0; b < nb; ++b) {
                pk[3 * b + 2] -= 1e-3 * std::min(k, 3);
                const Vec4 qb = quat_multiply(turn, Vec4(q[4 * b], q[4 * b + 1], q[4 * b + 2], q[4 * b + 3]));
                for (int c = 0; c < 4; ++c) qk[4 * b + c] = qb[c];
            }
            CHECK(hh_world_set_bone_targets(world, hand, nb, modes.data(), pk.data(), qk.data(), nullptr, nullptr) == HH_OK);
            hh_world_stats stats;
            CHECK(hh_world_step(world, &stats) == HH_OK);
        }
    }
};
}  // namespace

TEST(one_bone_bones_model_is_the_palm_handles_model) {
    PressedBox rig(4, 3, 2, nullptr, box_hand_params());
    rig.press(6);
    const World& w = rig.world->w;
    const CouplingModel palm = linearize_coupling(w, rig.hand);
    CHECK(palm.held_rows > 0);
    for (HeldSolves how : {HeldSolves::BoneColumns, HeldSolves::RowColumns}) {
        const BoneCouplingModel bones = linearize_bone_coupling(w, rig.hand, how);
        CHECK(bones.n_bones() == 1 && bones.held_rows == palm.held_rows);
        CHECK(relative(bones.wrench, palm.wrench) < 1e-14);
        CHECK_LT(relative(bones.stiffness, palm.stiffness), 1e-10);
    }
}

TEST(both_ways_of_forming_the_held_term_agree_on_three_bones) {
    hh_params p;
    hh_default_params(&p);
    std::vector<BoneDesc> bones(3);
    const double x[3][2] = {{0.0, 0.01}, {0.025, 0.035}, {0.05, 0.06}};
    for (int b = 0; b < 3; ++b) {
        bones[b].parent = b - 1;
        bones[b].head = Vec3(x[b][0], 0.01, 0.01);
        bones[b].tail = Vec3(x[b][1], 0.01, 0.01);
        bones[b].radius = 0.0145;
    }
    PressedBox rig(6, 2, 2, &bones, p);
    rig.press(6);
    const World& w = rig.world->w;
    const BoneCouplingModel by_bones = linearize_bone_coupling(w, rig.hand, HeldSolves::BoneColumns);
    const BoneCouplingModel by_rows = linearize_bone_coupling(w, rig.hand, HeldSolves::RowColumns);
    CHECK(by_bones.held_rows > 0 && by_bones.held_rows == by_rows.held_rows);
    CHECK(by_bones.n_bones() == 3 && by_bones.stiffness.rows() == 18);
    CHECK(by_bones.wrench == by_rows.wrench);
    CHECK_LT(relative(by_rows.stiffness, by_bones.stiffness), 1e-10);
    // the held contacts couple the bones: the end bones' blocks with each other are not zero
    const double coupled = by_bones.stiffness.topRightCorner(6, 6).cwiseAbs().maxCoeff();
    CHECK(coupled > 1e-6 * by_bones.stiffness.cwiseAbs().maxCoeff());
}

TEST(the_bones_model_refuses_a_hand_not_prescribed) {
    hh_params p;
    hh_default_params(&p);
    std::vector<BoneDesc> bones(2);
    bones[0].head = Vec3(0, 0.01, 0.01), bones[0].tail = Vec3(0.01, 0.01, 0.01), bones[0].radius = 0.0145;
    bones[1].parent = 0, bones[1].head = Vec3(0.05, 0.01, 0.01), bones[1].tail = Vec3(0.06, 0.01, 0.01), bones[1].radius = 0.0145;
    PressedBox rig(6, 2, 2, &bones, p);
    hh_world_stats stats;
    CHECK(hh_world_step(rig.world, &stats) == HH_OK);  // (the bones free)
    std::vector<double> w0(12), k(144);
    CHECK(hh_world_bone_coupling_model(rig.world, rig.hand, 2, w0.data(), k.data(), nullptr) == HH_ERR_INVALID_ARGUMENT);
    CHECK(std::string(hh_last_error()).find("every bone prescribed") != std::string::npos);
}
