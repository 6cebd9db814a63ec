// The C ABI never throws: bad input returns a status and a message naming the problem.
#include <cmath>
#include <cstring>
#include <limits>
#include <string>

#include "box_mesh.h"
#include "check.h"
#include "haptic_hand.h"

namespace {
hh_params params() { return box_hand_params(); }
// Creates a model from the box with params p; returns the status and keeps the message.
int create(const BoxMesh& b, const hh_params& p, std::string& message) {
    hh_model* m = nullptr;
    const int status = hh_model_create(b.nodes.data(), b.n_nodes(), b.tets.data(), b.n_tets(), &p, &m);
    message = hh_last_error();
    hh_model_free(m);
    return status;
}
bool mentions(const std::string& message, const char* word) { return message.find(word) != std::string::npos; }

// A valid model of the box rig and one data for it, freed at the end of the test.
struct Rig {
    BoxMesh box = make_box(4, 3, 2, 0.01);
    hh_model* m = nullptr;
    hh_data* d = nullptr;
    Rig() {
        const hh_params p = params();
        CHECK(hh_model_create(box.nodes.data(), box.n_nodes(), box.tets.data(), box.n_tets(), &p, &m) == HH_OK);
        CHECK(hh_data_create(m, &d) == HH_OK);
    }
    ~Rig() {
        hh_data_free(d);
        hh_model_free(m);
    }
};
}  // namespace

TEST(valid_model_steps_and_frees) {
    Rig rig;
    hh_model* m = rig.m;
    hh_data* d = rig.d;
    const double pos[3] = {0.02, 0.015, 0.012};
    CHECK(hh_set_device(d, 1, pos, nullptr, nullptr, nullptr) == HH_OK);
    hh_step_stats stats;
    for (int i = 0; i < 5; ++i) CHECK(hh_step(m, d, &stats) == HH_OK);
    CHECK(stats.t_total > 0);
    double diff = 1;
    CHECK(hh_compare_solvers(m, d, &diff) == HH_OK);
    CHECK_LT(diff, 1e-8);
}

TEST(bad_parameters_are_named) {
    const BoxMesh b = make_box(4, 3, 2, 0.01);
    std::string msg;
    hh_params p = params();
    p.young_modulus = std::numeric_limits<double>::quiet_NaN();
    CHECK(create(b, p, msg) == HH_ERR_INVALID_ARGUMENT && mentions(msg, "young_modulus"));
    p = params();
    p.density = -1;
    CHECK(create(b, p, msg) == HH_ERR_INVALID_ARGUMENT && mentions(msg, "density"));
    p = params();
    p.spring_stiffness = 0;
    CHECK(create(b, p, msg) == HH_ERR_INVALID_ARGUMENT && mentions(msg, "springs.stiffness"));
    p = params();
    p.poisson_ratio = 0.5;
    CHECK(create(b, p, msg) == HH_ERR_INVALID_ARGUMENT && mentions(msg, "poisson_ratio"));
    p = params();
    p.dt = 1.0;
    CHECK(create(b, p, msg) == HH_ERR_INVALID_ARGUMENT && mentions(msg, "dt"));
    p = params();
    p.struct_size = 8;
    CHECK(create(b, p, msg) == HH_ERR_INVALID_ARGUMENT && mentions(msg, "rebuild"));
}

TEST(bad_handles_are_named) {
    const BoxMesh b = make_box(4, 3, 2, 0.01);
    std::string msg;
    hh_params p = params();
    p.palm_seed[0] = 1.0;  // far outside the box
    CHECK(create(b, p, msg) == HH_ERR_INVALID_ARGUMENT && mentions(msg, "outside"));
    p = params();
    p.handle_radius = 0.004;  // catches no node: the seed sits between nodes
    CHECK(create(b, p, msg) == HH_ERR_INVALID_ARGUMENT && mentions(msg, "at least 4"));
    p = params();
    p.handle_radius = 1.0;  // catches everything
    CHECK(create(b, p, msg) == HH_ERR_INVALID_ARGUMENT && mentions(msg, "all"));
}

TEST(bad_meshes_are_named) {
    std::string msg;
    BoxMesh b = make_box(4, 3, 2, 0.01);
    std::swap(b.tets[1], b.tets[2]);  // invert tet 0
    CHECK(create(b, params(), msg) == HH_ERR_INVALID_ARGUMENT && mentions(msg, "inverted"));
    b = make_box(4, 3, 2, 0.01);
    b.tets[3] = b.tets[2];  // tet 0 loses a vertex: zero volume
    CHECK(create(b, params(), msg) == HH_ERR_INVALID_ARGUMENT && mentions(msg, "zero volume"));
    b = make_box(4, 3, 2, 0.01);
    b.tets[5] = 100000;
    CHECK(create(b, params(), msg) == HH_ERR_INVALID_ARGUMENT && mentions(msg, "outside"));
    b = make_box(4, 3, 2, 0.01);
    b.nodes[7] = std::numeric_limits<double>::infinity();
    CHECK(create(b, params(), msg) == HH_ERR_INVALID_ARGUMENT && mentions(msg, "non-finite"));
    CHECK(hh_model_create(nullptr, 0, nullptr, 0, nullptr, nullptr) == HH_ERR_INVALID_ARGUMENT);
}

TEST(wrong_array_sizes_are_rejected) {
    Rig rig;
    hh_model* m = rig.m;
    hh_data* d = rig.d;
    double x[3];
    CHECK(hh_get_state(m, d, x, nullptr, 1, nullptr, nullptr, nullptr, nullptr) == HH_ERR_INVALID_ARGUMENT);
    CHECK(mentions(hh_last_error(), "size"));
}
