// C entry points of a haptic session on a skeleton hand (docs/skeleton.md, Section 6; see
// haptic_hand.h): its gloves (external frames, the simulated glove user), the feedback groups,
// and the fetched frame's bones, groups and model.
#include <cmath>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "capi/session_handle.h"
#include "device/simulated_glove.h"
#include "haptics/session_bones.h"

using hh::capi::guard;
using hh::capi::require;
using hh::capi::require_fail_at;
using hh::capi::require_size;
using hh::capi::require_stopped;
using hh::capi::session_of;

namespace {
hh_session& bones_session(hh_session* session, int n_bones, const char* what) {
    hh_session& s = session_of(session);
    require_size(n_bones, s.s.n_bones(), what);
    return s;
}

// A glove finger's arm against the haptics.glove.* rows, the message naming the bone
void check_arm(const hh::ArmParams& arm, int bone) {
    try {
        hh::params::check("haptics.glove.mass", arm.mass);
        hh::params::check("haptics.glove.stiffness", arm.stiffness);
        hh::params::check("haptics.glove.damping", arm.damping);
    } catch (const hh::InvalidArgument& e) {
        throw hh::InvalidArgument("bone " + std::to_string(bone) + "'s arm: " + e.what());
    }
}

void put_wrench(const hh::Feedback& fb, double* out) {
    std::memcpy(out, fb.force.data(), 3 * sizeof(double));
    std::memcpy(out + 3, fb.torque.data(), 3 * sizeof(double));
}
// The simulated glove of hh_session_device_simulated_glove(_arms): bone b's arm is arms[3b ..
// 3b+3) (mass, stiffness, damping), posed where posed[b] != 0 (posed NULL: none).
int simulated_glove(hh_session* session, int n_bones, const double* times, const double* positions,
                    const double* quaternions, int n, const double* arms, const int* posed, double fail_at) {
    hh_session& s = bones_session(session, n_bones, "the simulated glove's fingers (one per bone)");
    require_stopped(s);
    require(n_bones > 1, "the hand has one handle: give it the simulated arm (hh_session_device_simulated)");
    require(times && positions && n >= 1, "a glove trajectory needs at least one timed pose per bone");
    require(arms != nullptr, "hh_session_device_simulated_glove_arms: null arms");
    require_fail_at(fail_at);
    std::vector<hh::SimulatedArm> fingers;
    std::vector<double> p(3 * n), q(4 * n);
    for (int b = 0; b < n_bones; ++b) {  // bone b's poses, out of the [n][B][.] arrays
        const hh::ArmParams arm{arms[3 * b], arms[3 * b + 1], arms[3 * b + 2], fail_at};
        check_arm(arm, b);
        for (int k = 0; k < n; ++k) {
            std::memcpy(&p[3 * k], positions + 3 * (k * n_bones + b), 3 * sizeof(double));
            if (quaternions) std::memcpy(&q[4 * k], quaternions + 4 * (k * n_bones + b), 4 * sizeof(double));
        }
        fingers.emplace_back(hh::capi::keyframes(times, p.data(), quaternions ? q.data() : nullptr, n), arm);
    }
    std::vector<char> is_posed(n_bones, 0);
    for (int b = 0; posed && b < n_bones; ++b) is_posed[b] = posed[b] != 0;
    s.s.set_device(std::make_unique<hh::SimulatedGlove>(std::move(fingers), std::move(is_posed)));
    return HH_OK;
}
}  // namespace

extern "C" {

int hh_session_bone_count(hh_session* session, int* out) {
    return guard([&] {
        require(out != nullptr, "hh_session_bone_count: null output");
        *out = session_of(session).s.n_bones();
        return HH_OK;
    });
}

int hh_session_device_external_frames(hh_session* session, int n_bones, double timeout) {
    return guard([&] {
        hh_session& s = bones_session(session, n_bones, "the external glove's frames (one per bone)");
        require_stopped(s);
        require(n_bones > 1, "the hand has one handle: give it the one-frame external device (hh_session_device_external)");
        hh::params::check("haptics.external_timeout", timeout);
        s.s.set_device(std::make_unique<hh::ExternalFrames>(s.s.bone_poses(), n_bones, timeout));
        return HH_OK;
    });
}

int hh_session_push_device_frames(hh_session* session, int n_bones, const double* positions, const double* quaternions) {
    return guard([&] {
        hh_session& s = bones_session(session, n_bones, "the glove's frames (one per bone)");
        require(positions && quaternions, "hh_session_push_device_frames: null pointer");
        require(s.s.external_frames() != nullptr,
                "this session's device is not an external glove (hh_session_device_external_frames): it reads its own poses");
        std::vector<hh::Pose> poses(n_bones);
        for (int b = 0; b < n_bones; ++b) {
            poses[b].position = hh::capi::vec3(positions + 3 * b);
            poses[b].quaternion = Eigen::Map<const hh::Vec4>(quaternions + 4 * b);
            require(poses[b].position.allFinite() && poses[b].quaternion.allFinite() && poses[b].quaternion.norm() > 1e-12,
                    "frame " + std::to_string(b) + " has NaN or infinite values or a zero quaternion");
            poses[b].quaternion.normalize();
        }
        s.s.external_frames()->push(poses.data(), n_bones);
        return HH_OK;
    });
}

int hh_session_device_feedback(hh_session* session, int n_bones, double* bones, int n_groups, double* groups,
                               double* time) {
    return guard([&] {
        hh_session& s = bones_session(session, n_bones, "the glove's feedback (one wrench per bone)");
        hh::ExternalFrames* device = s.s.external_frames();
        require(device != nullptr, "this session's device is not an external glove (hh_session_device_external_frames)");
        require_size(n_groups, s.s.n_groups(), "the feedback groups");
        device->fetch_feedback();
        const hh::FramesFeedback& f = device->feedback();
        for (int b = 0; bones && b < n_bones; ++b) put_wrench(f.bones[b], bones + 6 * b);
        for (int g = 0; groups && g < n_groups; ++g) put_wrench(f.groups[g], groups + 6 * g);
        if (time) *time = f.time;
        return HH_OK;
    });
}

int hh_session_device_simulated_glove(hh_session* session, int n_bones, const double* times, const double* positions,
                                      const double* quaternions, int n, double arm_mass, double arm_stiffness,
                                      double arm_damping, double fail_at) {
    return guard([&] {
        std::vector<double> arms;
        for (int b = 0; b < n_bones; ++b) arms.insert(arms.end(), {arm_mass, arm_stiffness, arm_damping});
        return simulated_glove(session, n_bones, times, positions, quaternions, n, arms.data(), nullptr, fail_at);
    });
}

int hh_session_device_simulated_glove_arms(hh_session* session, int n_bones, const double* times,
                                           const double* positions, const double* quaternions, int n,
                                           const double* arms, const int* posed, double fail_at) {
    return guard([&] { return simulated_glove(session, n_bones, times, positions, quaternions, n, arms, posed, fail_at); });
}

int hh_session_pose_fingers(hh_session* session, int n_bones, const double* times, const double* rel_positions,
                            const double* rel_quaternions, int n) {
    return guard([&] {
        hh_session& s = bones_session(session, n_bones, "the posed fingers (one script per bone)");
        require_stopped(s);
        require(n_bones > 1, "the hand has one handle: posed fingers ride on a skeleton hand's root");
        require(times && rel_positions && rel_quaternions && n >= 1,
                "hh_session_pose_fingers: null pointer, or no timed pose (give at least one)");
        std::vector<hh::Keyframes> fingers;
        std::vector<double> p(3 * n), q(4 * n);
        for (int b = 1; b < n_bones; ++b) {  // bone b's poses, out of the [n][B][.] arrays
            for (int k = 0; k < n; ++k) {
                const double* pk = rel_positions + 3 * (k * n_bones + b);
                const double* qk = rel_quaternions + 4 * (k * n_bones + b);
                const double norm = std::sqrt(qk[0] * qk[0] + qk[1] * qk[1] + qk[2] * qk[2] + qk[3] * qk[3]);
                require(std::isfinite(pk[0]) && std::isfinite(pk[1]) && std::isfinite(pk[2]) && std::isfinite(norm),
                        "bone " + std::to_string(b) + "'s pose relative to the root at time index " +
                            std::to_string(k) + " has NaN or infinite values");
                // float32 sources round a unit quaternion's norm to ~1e-7: within 1e-4 it is normalized
                require(std::abs(norm - 1) < 1e-4, "bone " + std::to_string(b) + "'s quaternion relative to the root "
                        "at time index " + std::to_string(k) + " has norm " + std::to_string(norm) +
                        ": give unit quaternions (x, y, z, s)");
                std::memcpy(&p[3 * k], pk, 3 * sizeof(double));
                for (int i = 0; i < 4; ++i) q[4 * k + i] = qk[i] / norm;
            }
            try {
                fingers.emplace_back(times, p.data(), q.data(), n);  // checks the times
            } catch (const hh::InvalidArgument& e) {
                throw hh::InvalidArgument(std::string("hh_session_pose_fingers: the posed fingers' times: ") + e.what());
            }
        }
        s.s.pose_fingers(std::move(fingers));
        return HH_OK;
    });
}

int hh_session_set_feedback_groups(hh_session* session, int n_bones, const int* group_of_bone, int n_groups) {
    return guard([&] {
        hh_session& s = bones_session(session, n_bones, "the feedback groups (one group or -1 per bone)");
        require_stopped(s);
        require(group_of_bone != nullptr && n_groups >= 0 && n_groups <= n_bones,
                "hh_session_set_feedback_groups: null groups, or a group count below 0 or above the bones'");
        require(n_groups == 0 || !s.s.fingers_posed(),
                "this session's fingers are posed on a one-frame wrist device (hh_session_pose_fingers), which "
                "renders one wrench, the whole hand's: feedback groups need a glove of one frame per bone");
        s.s.set_feedback_groups(hh::FeedbackGroups(std::vector<int>(group_of_bone, group_of_bone + n_bones), n_groups));
        return HH_OK;
    });
}

int hh_session_frame_bones(hh_session* session, int n_bones, double* handles, double* proxies, double* devices,
                           double* feedback) {
    return guard([&] {
        hh_session& s = bones_session(session, n_bones, "the frame's bones");
        require(n_bones > 1, "the hand has one handle: its frame is hh_session_fetch_frame's");
        const hh::Frame& f = s.s.frame();
        const auto copy = [](const std::vector<double>& from, double* to) {
            if (to) std::memcpy(to, from.data(), from.size() * sizeof(double));
        };
        copy(f.bone_handles, handles);
        copy(f.bone_proxies, proxies);
        copy(f.bone_devices, devices);
        copy(f.bone_feedback, feedback);
        return HH_OK;
    });
}

int hh_session_frame_groups(hh_session* session, int n_groups, double* feedback) {
    return guard([&] {
        hh_session& s = session_of(session);
        require_size(n_groups, s.s.n_groups(), "the feedback groups");
        require(feedback != nullptr || n_groups == 0, "hh_session_frame_groups: null output");
        if (n_groups) std::memcpy(feedback, s.s.frame().group_feedback.data(), 6 * n_groups * sizeof(double));
        return HH_OK;
    });
}

int hh_session_bone_coupling_model(hh_session* session, int n_bones, double* wrench0, double* stiffness, int* held_rows) {
    return guard([&] {
        hh_session& s = bones_session(session, n_bones, "the bones' model");
        require(n_bones > 1, "the hand has one handle: its model is hh_session_coupling_model's");
        const hh::Frame& f = s.s.frame();
        if (wrench0) std::memcpy(wrench0, f.bone_wrench.data(), f.bone_wrench.size() * sizeof(double));
        if (stiffness) std::memcpy(stiffness, f.bone_stiffness.data(), f.bone_stiffness.size() * sizeof(double));
        if (held_rows) *held_rows = f.held_rows;
        return HH_OK;
    });
}

}  // extern "C"
