// The data of one step's contact solve, shared by its parts (sim/world_contact.cpp) and held
// by the World between them (the step runs them as tasks, sim/world.cpp).
#pragma once
#include <chrono>
#include <map>
#include <memory>
#include <utility>
#include <vector>

#include "sim/world.h"

namespace hh {

// Per contact and dynamic side: the body's unknowns it moves, as (first unknown, weight) terms
// for flesh nodes (3 unknowns each) or the rigid body's (v, omega) lever arm.
struct ContactTerm {
    int offset;
    double weight;
    bool rigid;
    Vec3 r;
};

// One side of a contact on its body's unknowns: the terms of J's rows (sign: +1 for side a, -1
// for side b)
void append_side_terms(const Body& b, const ContactSide& side, double sign, std::vector<ContactTerm>& ts);

// Identity of a contact across steps (the warm start's key)
std::uint64_t contact_key(const Contact& c);

// One step's contact solve, from prepare_contacts to finish_contacts.
struct World::ContactSetup {
    std::chrono::steady_clock::time_point start;
    int nc = 0, rows = 0;
    std::vector<std::vector<std::pair<int, std::vector<ContactTerm>>>> sides;  // contact -> (body, terms)
    std::vector<int> involved;                   // dynamic bodies, ascending
    std::vector<std::vector<int>> group_bodies;  // per group: its dynamic bodies, ascending
    VecX u_free, gap, friction, kinetic;         // per row / contact (u_free: kinematic bodies' part first)
    VecX lambda;                                 // impulses: the warm start, then the groups' solutions
    int warm_hits = 0, patch_hits = 0;
    // per body, between the parts of its build (begin_contact_body .. finish_contact_body)
    struct Build {
        Eigen::SparseMatrix<double> gt;  // G^T: touched x rows, column-major
        std::vector<int> touched_nodes;  // soft body: the nodes of the touched unknowns
        int first = 0;                   // K's columns from here on come from the solves
        // unit columns on the step's Cholesky factor: K's columns solved in this order (by the
        // factor's elimination order of their nodes), so a batch's units share their paths
        std::vector<int> unit_order;
        // A^-1 itself at the touched unknowns (a soft body, or a skeleton hand with every bone
        // prescribed, whose touched unknowns are the flesh's: A_t's factor), symmetric:
        // each batch of unit columns is solved at the rows of its own and later units only (the
        // upper triangle in elimination order, whose paths through the factor are shorter), the
        // rest mirrored (mirror_upper)
        bool upper = false;
    };
    std::map<int, Build> build;
    std::map<int, MatX> response;  // per body: its symmetrized C_b (see ReducedContactProblem)
    // per group, between setup_contact_group and solve_contact_group: its problem, impulses
    // (the warm start) and the sweeps' columns, formed in shares (form_contact_columns)
    struct GroupSolve {
        ReducedContactProblem problem;
        VecX lambda;
        std::unique_ptr<ReducedColumns> columns;
        std::vector<double> form_seconds;  // per share
        bool shared = false;               // formed in shares (else all at setup)
        int formed = 0;                    // contacts whose columns were formed (shares and sweeps)
    };
    std::vector<GroupSolve> group_solve;
    std::map<int, VecX> u_body;    // per body: its share of u_free on its rows
};

}  // namespace hh
