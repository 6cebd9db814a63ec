// A scene of several bodies simulated together in the visual loop: the hand (flesh + handle),
// soft FEM bodies, free rigid bodies, kinematic bodies moved along a script, static meshes and
// planes. One step: every dynamic body formulates and solves its own implicit system (the
// hand through the Schur complement), contacts are detected at the start of the step, and the
// contact impulses are solved together with the implicit step through each body's black-box
// solve (Delassus operator W = J A^-1 J^T, projected Gauss-Seidel), then all bodies advance.
#pragma once
#include <cstdint>
#include <cstdio>
#include <map>
#include <memory>
#include <unordered_map>
#include <vector>

#include "common/worker.h"
#include "contact/detection.h"
#include "contact/pgs.h"
#include "sim/body.h"

namespace hh {

struct ContactTerm;  // (sim/world_contact.h)

// The world's settings: the hh_world_params rows of the parameter table (their meanings and
// ranges are there); a default-constructed one holds the table's defaults.
struct WorldSettings {
    WorldSettings();
    explicit WorldSettings(const hh_world_params& p);
    double dt;
    Vec3 gravity;
    double contact_thickness;  // m: surfaces are kept this far apart
    double contact_patch;      // m: one contact per cell of this size per pair of bodies
    int max_iterations;        // projected Gauss-Seidel sweeps (resting contacts end far sooner)
    double tolerance;          // m/s: largest constraint velocity error that ends the sweeps
    // the sweeps also end once they stall within this factor of the tolerance (solve_pgs); 0: never
    double stall_factor;
    // 2: a second thread takes parts of the step (detection, bodies' solves, contact groups)
    // beside the caller's (the results are the same as with 1, bit for bit: only parts that do
    // not depend on each other run side by side; see World::step)
    int threads;
    // speculative contacts whose points separate at the start of the step wait outside the
    // contact solve, which runs again with them if one would close (sim/world_speculative.cpp)
    bool defer_separating;
};

struct WorldStats {
    int contacts = 0;
    int self_contacts = 0;
    double max_penetration = 0;  // m: deepest a contact ended inside the thickness layer
    double min_distance = 0;     // m: smallest signed distance of a contact after the step
    double residual = 0;         // m/s: largest constraint violation left by the solver
    int iterations = 0;
    // t_total is the step's wall time; with two threads detection and dynamics overlap (and
    // t_dynamics sums the bodies' free solves, whichever thread ran them)
    double t_detection = 0, t_dynamics = 0, t_contact = 0, t_total = 0;  // s
    // inside t_contact: forming the groups' W (the bodies' batched solves included), the
    // Gauss-Seidel sweeps, and the final velocity solves
    double t_contact_build = 0, t_contact_sweeps = 0, t_contact_apply = 0;  // s
    int contact_groups = 0;
};

class World {
public:
    explicit World(const WorldSettings& settings);
    ~World();
    WorldSettings settings;
    std::vector<std::unique_ptr<Body>> bodies;
    std::vector<Contact> contacts;  // of the last step, one per patch
    std::vector<Contact> detected;  // every pair found within reach, before the reduction
    // of the last step: the speculative contacts left out of its contact solve, their points
    // separating (settings.defer_separating; empty when it solved again with them)
    std::vector<Contact> deferred;
    WorldStats stats;
    // impulses of the last step's contacts (world frame, N s), by contact identity, to warm
    // start the next step's solve: a resting contact's impulse changes little between steps
    std::unordered_map<std::uint64_t, Vec3> previous_impulse;
    // the same by patch (pair of bodies, cell, element, normal octant): when another vertex
    // becomes the deepest of a patch, its contact starts from the patch's last impulse
    std::unordered_map<std::uint64_t, Vec3> previous_patch_impulse;
    std::vector<double> motion_;  // per body: how far its fastest point moves in the step (detect)
    std::vector<std::uint64_t> contact_patch_keys;  // per contact of the last step
    // The last contact solve, kept for the handle-space linearization (haptics/coupling_model).
    // Contacts are grouped by the dynamic bodies they share (contacts of bodies that do not
    // touch, directly or through other bodies, do not couple: W = J A^-1 J^T is block diagonal
    // over the groups), each group solved on its own. W is not formed: per body, the response
    // K on the unknowns the contacts touch (or on its rows) and J_b on them (G) are kept, so
    // W_b = G K G^T (or G K); contact_delassus() forms the entries asked for.
    struct ContactGroup {
        std::vector<int> contacts;  // contact indices, ascending
        int iterations = 0;         // Gauss-Seidel sweeps this group took
        double residual = 0;        // m/s, left by them
    };
    // One dynamic body's part: its response to impulses on the unknowns the contacts act on.
    struct ContactBody {
        std::vector<int> rows;      // global contact rows the body takes part in, ascending
        std::vector<int> touched;   // the body's unknowns those rows act on, ascending
        bool row_basis = false;     // K's columns: per row (A^-1 J_b^T e_row) or per touched unknown (A^-1 e_k)
        MatX K;                     // touched x (rows or touched): those columns at the touched unknowns
        Eigen::SparseMatrix<double, Eigen::RowMajor> G;  // rows x touched: J_b on the touched unknowns
        std::vector<int> local_row;  // per global row: index in `rows`, or -1
        // the hand with a prescribed handle: per row, J_b A_t^-1 [Ath | Aht^T] (rows x 12, Aht
        // at the handle's end-of-step pose, Data::end_aht), for the handle-space linearization
        // (contact_handle_terms); else empty
        MatX handle_terms;
        // P f of the body's carried impulses still in its free velocities (Body::carried_pending)
        // at the touched unknowns (World::read_carried); empty when none is pending
        VecX carried_at_touched;
    };
    std::vector<ContactGroup> contact_groups;
    std::vector<int> contact_group_of;  // per contact: its group
    std::vector<int> contact_slot;      // per contact: its index within its group
    std::map<int, ContactBody> contact_bodies;  // per dynamic body in the contact solve
    VecX contact_lambda;    // 3c impulses (N s) in the contact frames
    VecX contact_friction;  // c static friction coefficients
    VecX contact_velocity;  // 3c relative velocities after the step, in the contact frames
    // Entries of the last step's W (unsymmetrized) for the given global rows: zero between
    // rows of different groups.
    MatX contact_delassus(const std::vector<int>& rows) const;
    // The hand (prescribed handle) in a contact row of the last step: what the handle-space
    // linearization reads from the row's response A^-1 J^T e_row at the handle nodes, without
    // those rows (At symmetric): through_ath = Ath^T A_t^-1 J^T e_row = (J A_t^-1 Ath)_row^T and
    // through_aht = Aht A_t^-1 J^T e_row. False when the hand is not in that row.
    bool contact_handle_terms(int body, int row, Vec6& through_ath, Vec6& through_aht) const;
    double time = 0;  // s: simulated time, advanced by step()
    // When set (C++ only, for measurements), every step writes its contact solve's parts here:
    // warm-start hits, contacts, groups, the build / sweeps / apply times, the columns formed, and
    // each body's rows and touched unknowns
    std::FILE* contact_trace = nullptr;

    int add(std::unique_ptr<Body> body);
    void step();

private:
    // Detection in parts (sim/world_detection.cpp; step runs them as tasks): the pairs to look
    // at and each body's reach, each body's surface, each pair, then every pair's contacts
    // gathered and reduced.
    struct DetectionJob {
        int a, b;      // bodies (a == b: self-contact)
        double reach;  // m
        std::vector<Contact> found;
    };
    std::vector<DetectionJob> detection_jobs_;
    std::vector<double> surface_reach_;  // per body: its tree's margin
    std::vector<Vec3> drift_;            // per body: Body::drift, the frames pairs are seen from
    double base_reach_ = 0;              // m: the reach of pairs at rest
    void begin_detection();
    double pair_closing(int a, int b) const;
    void drop_beyond_own_reach(DetectionJob& job) const;
    void update_body_surface(int body);
    void detect_job(int job);
    void finish_detection();
    void reduce_contacts();
    // Speculative contacts set aside while their points separate (sim/world_speculative.cpp)
    std::vector<std::uint64_t> deferred_patch_keys_;
    void defer_separating_contacts();
    Vec3 start_velocity(const ContactSide& side) const;
    double solved_normal_velocity(const Contact& k, std::vector<ContactTerm>& terms) const;
    bool a_deferred_contact_closes() const;
    void take_back_deferred_contacts();
    // Each dynamic body's free solve (sim/world.cpp)
    void solve_free(Body& b);
    void solve_free_skeleton(Body& b);
    void assemble_hand(Body& b);
    // The contact solve in parts (sim/world_contact.cpp), scheduled by step as tasks: prepare
    // from the contacts alone; per dynamic body, once its free solve is done, its responses;
    // per group of coupled contacts, once its bodies are built, the sweeps; per body, once its
    // group is solved, its final velocity solve; then finish.
    struct ContactSetup;
    std::unique_ptr<ContactSetup> setup_;
    void prepare_contacts();
    double contact_gap(const Contact& k) const;         // distance less thickness, with the hand's turn
    Vec3 kinematic_velocity(const Contact& k) const;    // a kinematic side's carried velocity (a less b)
    // a body's responses in three kinds of part: begin (its unknowns and J_b), the black-box
    // solves in contact_body_parts shares that may run side by side, finish (C_b, u_free)
    int contact_body_parts(int body) const;  // (after prepare_contacts)
    void begin_contact_body(int body);  // (reads only the contacts: may run beside the body's free solve)
    void ready_contact_body(int body);  // after both: the body's factor ready for solves side by side
    bool flesh_alone(int body) const;
    static bool loads_flesh_alone(const Body& b, bool on_bones);
    static const Beside& flesh_beside(const Body& b);
    bool units_at_touched_rows(int body) const;
    bool rows_cost_less(int body) const;  // the basis of the body's responses (ready_contact_body)
    bool kept_units(int body);
    std::vector<int> touched_flesh(int body) const;
    // the carried impulses' response (sim/world_carried.cpp)
    bool defers_carried(const Body& b, const VecX& carried) const;
    VecX lagged_response(Body& b, const VecX& load);
    void take_out_carried(int body);
    void read_carried(int body);
    VecX impulse_pass_load(const Body& b, const VecX& impulses) const;
    void form_handle_terms(int body);  // a hand's ContactBody::handle_terms
    bool handle_terms_apart(int body) const;
    void solve_contact_body(int body, int part, int parts);
    void finish_contact_body(int body);
    void solve_upper_units(int body, int first, int w);
    void mirror_upper(int body);
    // a group's sweeps in parts too: setup (its problem), the columns in shares, the sweeps
    static constexpr int kColumnShares = 2;
    void setup_contact_group(int group);
    void form_contact_columns(int group, int part);
    void solve_contact_group(int group);
    void apply_contact_body(int body);
    void finish_contacts();
    void trace_contacts() const;
    const std::vector<int>& contact_involved() const;               // (after prepare_contacts)
    const std::vector<int>& contact_group_bodies(int group) const;  // (after prepare_contacts)
    // The step's schedule (sim/world_schedule.cpp): its tasks, and the times they write
    struct StepTasks;
    void move_kinematic_targets();
    void add_free_solves(StepTasks& tasks);
    void add_detection(StepTasks& tasks);
    void add_contact_solve(StepTasks& tasks);
    void add_contact_bodies(StepTasks& tasks, std::vector<int>& built);
    void add_contact_groups(StepTasks& tasks, const std::vector<int>& built);
    void sum_step_times(const StepTasks& tasks, double finish_seconds);
    void add_contact_times(const StepTasks& tasks);
    std::unique_ptr<StepTasks> solve_contacts_again();
    void measure_contacts();
    void integrate();
    double contact_distance(const Contact& c) const;
    std::unique_ptr<Worker> worker_;  // settings.threads > 1
};

}  // namespace hh
