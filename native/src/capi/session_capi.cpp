// C entry points of haptic sessions and scripted kinematic bodies (see haptic_hand.h).
#include <cmath>
#include <cstring>
#include <memory>

#include "capi/session_handle.h"
#include "device/openhaptics.h"
#include "device/playback.h"
#include "device/simulated_arm.h"

using hh::capi::guard;
using hh::capi::keyframes;
using hh::capi::require;
using hh::capi::require_fail_at;
using hh::capi::require_stopped;
using hh::capi::session_of;

namespace {
// Every field against the table, then what holds between fields: the haptic loop's stability.
void validate_session_params(const hh_session_params& p) {
    hh::params::validate(HH_STRUCT_SESSION_PARAMS, &p);
    require(p.coupling_stiffness <= HH_HAPTIC_MAX_COUPLING_STIFFNESS,
            "coupling.stiffness = " + std::to_string(p.coupling_stiffness) +
                " N/m is invalid with the haptic loop on: it must be at most " HH_STR(HH_HAPTIC_MAX_COUPLING_STIFFNESS)
                " N/m, the stiffest coupling the haptic loop is tested stable at; lower it (1e3 to 3e3 N/m suits a "
                "desktop device)");
    const hh::SessionParams s(p);
    hh::check_passive(s.coupling, s.haptic_rate);
}
void put_pose(const double* in, double* out) { std::memcpy(out, in, 7 * sizeof(double)); }
}  // namespace

extern "C" {

int hh_log_columns(void) {
    static_assert(hh::kLogColumns == HH_LOG_COLUMNS, "the haptic log's rows are HH_LOG_COLUMNS wide");
    return HH_LOG_COLUMNS;
}

int hh_session_params_check(const hh_session_params* params) {
    return guard([&] {
        require(params != nullptr, "hh_session_params_check: null pointer");
        validate_session_params(*params);
        return HH_OK;
    });
}

int hh_session_create(hh_world* world, int hand_body, const hh_session_params* params, hh_session** out) {
    return guard([&] {
        require(world && params && out, "hh_session_create: null pointer");
        validate_session_params(*params);
        require(!world->in_live_session(),
                "a live session is stepping this world: stop it before creating another session on it");
        const hh::SessionParams p(*params);
        *out = new hh_session(world, hand_body, p);
        return HH_OK;
    });
}

void hh_session_free(hh_session* session) {
    if (!session) return;
    session->s.stop();
    session->world->release(session);  // only if this session holds the world
    delete session;
}

int hh_session_device_simulated(hh_session* session, const double* times, const double* positions,
                                const double* quaternions, int n, double arm_mass, double arm_stiffness,
                                double arm_damping, double fail_at) {
    return guard([&] {
        hh_session& s = session_of(session);
        require_stopped(s);
        hh::params::check("haptics.arm.mass", arm_mass);
        hh::params::check("haptics.arm.stiffness", arm_stiffness);
        hh::params::check("haptics.arm.damping", arm_damping);
        require_fail_at(fail_at);
        hh::ArmParams arm{arm_mass, arm_stiffness, arm_damping, fail_at};
        s.s.set_device(std::make_unique<hh::SimulatedArm>(keyframes(times, positions, quaternions, n), arm));
        return HH_OK;
    });
}

int hh_session_device_playback(hh_session* session, const double* times, const double* positions,
                               const double* quaternions, int n, double fail_at) {
    return guard([&] {
        hh_session& s = session_of(session);
        require_stopped(s);
        require_fail_at(fail_at);
        s.s.set_device(std::make_unique<hh::Playback>(keyframes(times, positions, quaternions, n), fail_at));
        return HH_OK;
    });
}

int hh_session_device_external(hh_session* session, double timeout) {
    return guard([&] {
        hh_session& s = session_of(session);
        require_stopped(s);
        hh::params::check("haptics.external_timeout", timeout);
        s.s.set_device(std::make_unique<hh::ExternalDevice>(s.s.handle_pose(), timeout));
        return HH_OK;
    });
}

int hh_session_push_device_pose(hh_session* session, const double position[3], const double quaternion[4]) {
    return guard([&] {
        hh_session& s = session_of(session);
        require(position && quaternion, "hh_session_push_device_pose: null pointer");
        require(s.s.external_device() != nullptr, "this session's device is not 'external': it reads its own pose");
        hh::Pose p;
        p.position = hh::Vec3(position[0], position[1], position[2]);
        p.quaternion = hh::Vec4(quaternion[0], quaternion[1], quaternion[2], quaternion[3]);
        require(p.position.allFinite() && p.quaternion.allFinite() && p.quaternion.norm() > 1e-12,
                "the device pose has NaN or infinite values or a zero quaternion");
        p.quaternion.normalize();
        s.s.external_device()->push(p);
        return HH_OK;
    });
}

int hh_session_device_openhaptics(hh_session* session, const char* library, double workspace_scale,
                                  const double workspace_origin[3], double max_force) {
    return guard([&] {
        hh_session& s = session_of(session);
        require_stopped(s);
        hh::params::check("haptics.openhaptics.workspace_scale", workspace_scale);
        require(std::isfinite(max_force) && max_force > 0, "the device's force limit must be > 0");
        hh::OpenHapticsParams p;
        if (library) p.library = library;
        p.workspace_scale = workspace_scale;
        if (workspace_origin) p.workspace_origin = hh::capi::vec3(workspace_origin);
        p.max_force = max_force;
        s.s.set_device(std::make_unique<hh::OpenHapticsDevice>(p));
        return HH_OK;
    });
}

int hh_session_run_offline(hh_session* session, int visual_steps) {
    return guard([&] {
        hh_session& s = session_of(session);
        require(visual_steps >= 0, "the number of visual steps must be >= 0");
        const hh_session* live = s.world->live_session.load(std::memory_order_acquire);
        require(live == nullptr || live == session,
                "another live session is stepping this world: stop that session before stepping this one offline");
        s.s.run_offline(visual_steps);
        return HH_OK;
    });
}

int hh_session_start(hh_session* session) {
    return guard([&] {
        hh_session& s = session_of(session);
        if (s.s.running()) return HH_OK;
        require(s.world->claim(session),
                "another live session is stepping this world: stop that session before starting this one");
        try {
            s.s.start();
        } catch (...) {
            s.world->release(session);
            throw;
        }
        return HH_OK;
    });
}

int hh_session_stop(hh_session* session) {
    return guard([&] {
        hh_session& s = session_of(session);
        s.s.stop();
        s.world->release(session);
        return HH_OK;
    });
}

int hh_session_get_status(hh_session* session, hh_session_status* out) {
    return guard([&] {
        hh_session& s = session_of(session);
        require(out != nullptr, "hh_session_get_status: null output");
        out->failed = s.s.failed() ? 1 : 0;
        out->running = s.s.running() && !out->failed ? 1 : 0;
        out->haptic_steps = static_cast<double>(s.s.haptic_steps());
        out->visual_steps = static_cast<double>(s.s.visual_steps());
        out->log_unread = static_cast<double>(s.s.log().unread());
        out->log_dropped = static_cast<double>(s.s.log().dropped());
        out->realtime = s.s.realtime() ? 1 : 0;
        std::snprintf(out->message, sizeof out->message, "%s", s.s.error());
        return HH_OK;
    });
}

int hh_session_loop_info(hh_session* session, int* cpu, int* cpu_isolated, double* locked_bytes,
                         double* unlocked_bytes, double* minor_faults, double* major_faults) {
    return guard([&] {
        hh_session& s = session_of(session);
        require_stopped(s);
        const hh::LoopSetup& l = s.s.loop_setup();
        if (cpu) *cpu = l.cpu;
        if (cpu_isolated) *cpu_isolated = l.cpu_isolated ? 1 : 0;
        if (locked_bytes) *locked_bytes = l.locked_bytes;
        if (unlocked_bytes) *unlocked_bytes = l.unlocked_bytes;
        if (minor_faults) *minor_faults = s.s.loop_minor_faults();
        if (major_faults) *major_faults = s.s.loop_major_faults();
        return HH_OK;
    });
}

int hh_session_fetch_frame(hh_session* session, int* out_new, hh_session_frame* out) {
    return guard([&] {
        hh_session& s = session_of(session);
        const bool fresh = s.s.fetch_frame();
        if (out_new) *out_new = fresh ? 1 : 0;
        if (out) {
            const hh::Frame& f = s.s.frame();
            out->time = f.time;
            out->visual_steps = static_cast<double>(f.visual_steps);
            put_pose(f.handle, out->handle);
            put_pose(f.proxy, out->proxy);
            put_pose(f.device, out->device);
            std::memcpy(out->feedback, f.feedback, sizeof f.feedback);
            std::memcpy(out->wrench, f.wrench, sizeof f.wrench);
            out->contacts = f.contacts;
            out->held_rows = f.held_rows;
        }
        return HH_OK;
    });
}

int hh_session_frame_surface(hh_session* session, int body, double* out, int n_vertices) {
    return guard([&] {
        hh_session& s = session_of(session);
        const auto& offsets = s.s.surface_offsets();
        require(body >= 0 && body < static_cast<int>(offsets.size()) && offsets[body] >= 0,
                "body " + std::to_string(body) + " has no collision surface in this world");
        const int next_offset = [&] {
            for (std::size_t b = body + 1; b < offsets.size(); ++b)
                if (offsets[b] >= 0) return offsets[b];
            return static_cast<int>(s.s.frame().surfaces.size() / 3);
        }();
        hh::capi::require_size(n_vertices, next_offset - offsets[body], "surface vertices");
        require(out != nullptr, "hh_session_frame_surface: null output");
        const double* src = s.s.frame().surfaces.data() + 3 * offsets[body];
        std::memcpy(out, src, 3 * sizeof(double) * n_vertices);
        return HH_OK;
    });
}

int hh_session_frame_pose(hh_session* session, int body, double pose[7]) {
    return guard([&] {
        hh_session& s = session_of(session);
        const hh::Frame& f = s.s.frame();
        require(body >= 0 && 7 * static_cast<std::size_t>(body) < f.poses.size(), "no such body in this world");
        require(pose != nullptr, "hh_session_frame_pose: null output");
        std::memcpy(pose, f.poses.data() + 7 * body, 7 * sizeof(double));
        return HH_OK;
    });
}

int hh_session_read_log(hh_session* session, double* out, int capacity, int* out_rows) {
    return guard([&] {
        hh_session& s = session_of(session);
        require(out && out_rows && capacity >= 0, "hh_session_read_log: null pointer or negative capacity");
        *out_rows = static_cast<int>(s.s.log().read(out, static_cast<std::size_t>(capacity)));
        return HH_OK;
    });
}

int hh_session_coupling_model(hh_session* session, double wrench0[6], double stiffness[36], int* held_rows) {
    return guard([&] {
        hh_session& s = session_of(session);
        const hh::Frame& f = s.s.frame();
        if (wrench0) std::memcpy(wrench0, f.wrench, sizeof f.wrench);
        if (stiffness) std::memcpy(stiffness, f.stiffness, sizeof f.stiffness);
        if (held_rows) *held_rows = f.held_rows;
        return HH_OK;
    });
}

int hh_world_set_script(hh_world* world, int body, const double* times, const double* positions,
                        const double* quaternions, int n) {
    return guard([&] {
        require(world != nullptr, "null world");
        require(!world->in_live_session(), "a live session is stepping this world: stop it first");
        require(body >= 0 && body < static_cast<int>(world->w.bodies.size()), "no such body");
        hh::Body& b = *world->w.bodies[body];
        require(b.kind == hh::BodyKind::Kinematic, "only kinematic bodies follow a script");
        b.mesh.script = keyframes(times, positions, quaternions, n);
        return HH_OK;
    });
}

int hh_world_coupling_model(const hh_world* world, int hand_body, double wrench0[6], double stiffness[36],
                            int* held_rows) {
    return guard([&] {
        require(world != nullptr, "null world");
        require(!world->in_live_session(), "a live session is stepping this world: ask the session instead");
        const hh::CouplingModel m = hh::linearize_coupling(world->w, hand_body);
        for (int i = 0; i < 6; ++i) {
            if (wrench0) wrench0[i] = m.wrench[i];
            for (int j = 0; j < 6; ++j)
                if (stiffness) stiffness[6 * i + j] = m.stiffness(i, j);
        }
        if (held_rows) *held_rows = m.held_rows;
        return HH_OK;
    });
}

int hh_world_time(const hh_world* world, double* out) {
    return guard([&] {
        require(world && out, "hh_world_time: null pointer");
        *out = world->w.time;
        return HH_OK;
    });
}

}  // extern "C"
