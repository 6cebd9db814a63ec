// The wrist glove (device/wrist_glove.h): a one-frame device on the wrist carrying the posed
// fingers. Its frames against the rigid composition T_b = T_wrist rel_b under a turning wrist,
// their velocities against central differences of the frames, its commanded wrench against a
// hand-computed sum with the lever arms, the clamp on that sum, a failing wrist, and no heap
// allocation in its haptic-thread calls.
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <memory>
#include <new>
#include <string>

#include "check.h"
#include "device/playback.h"
#include "device/wrist_glove.h"

#include "count_allocations.h"

using namespace hh;

namespace {
constexpr double kPi = 3.14159265358979323846;

Vec4 turn(const Vec3& axis, double angle) {
    const Vec3 a = axis.normalized() * std::sin(angle / 2);
    return Vec4(a.x(), a.y(), a.z(), std::cos(angle / 2));
}
// q o (r, 0) o q': the rotation by the quaternion product, not by quat_to_matrix
Vec3 rotate(const Vec4& q, const Vec3& r) {
    return quat_multiply(quat_multiply(q, Vec4(r.x(), r.y(), r.z(), 0)), quat_conjugate(q)).head<3>();
}
// Two timed poses 0 -> 1 s: from (p0, q0) to (p1, q1)
Keyframes motion(const Vec3& p0, const Vec4& q0, const Vec3& p1, const Vec4& q1) {
    const double t[2] = {0, 1};
    const double p[6] = {p0.x(), p0.y(), p0.z(), p1.x(), p1.y(), p1.z()};
    const double q[8] = {q0[0], q0[1], q0[2], q0[3], q1[0], q1[1], q1[2], q1[3]};
    return Keyframes(t, p, q, 2);
}

// The wrist turning 90 degrees about (1, 1, 1) while it moves 10 cm; finger 1 at rest on it,
// finger 2 turning 0.6 rad about its own x and sliding 1 cm (a finger curling on the hand).
const Vec3 kAxis = Vec3(1, 1, 1).normalized();
std::unique_ptr<Device> turning_wrist(double fail_at = 1e300) {
    return std::make_unique<Playback>(
        motion(Vec3(0.1, 0.2, 0.3), turn(Vec3(0, 0, 1), 0.2), Vec3(0.2, 0.2, 0.3), turn(kAxis, kPi / 2)), fail_at);
}
std::vector<Keyframes> two_fingers() {
    std::vector<Keyframes> f;
    f.push_back(motion(Vec3(0.08, 0.01, 0), turn(Vec3(0, 1, 0), 0.3), Vec3(0.08, 0.01, 0), turn(Vec3(0, 1, 0), 0.3)));
    f.push_back(motion(Vec3(0.05, -0.02, 0.01), turn(Vec3(1, 0, 0), 0.0), Vec3(0.06, -0.02, 0.01),
                       turn(Vec3(1, 0, 0), 0.6)));
    return f;
}

// A one-frame device held still, turned 90 degrees about z, that keeps what it is commanded
struct Held : Device {
    const char* name() const override { return "held"; }
    bool read(double, Pose& out) noexcept override {
        out.position = Vec3(0.3, 0, 0.1);
        out.quaternion = turn(Vec3(0, 0, 1), kPi / 2);
        return true;
    }
    void command(const Feedback& fb) noexcept override { got = fb; }
    Feedback got;
};
std::vector<Keyframes> still_fingers() {  // finger 1 10 cm along the wrist's x, finger 2 5 cm along its z
    std::vector<Keyframes> f;
    f.push_back(motion(Vec3(0.1, 0, 0), Vec4(0, 0, 0, 1), Vec3(0.1, 0, 0), Vec4(0, 0, 0, 1)));
    f.push_back(motion(Vec3(0, 0, 0.05), Vec4(0, 0, 0, 1), Vec3(0, 0, 0.05), Vec4(0, 0, 0, 1)));
    return f;
}
Feedback wrench(const Vec3& f, const Vec3& t) {
    Feedback fb;
    fb.force = f;
    fb.torque = t;
    return fb;
}
}  // namespace

TEST(finger_frames_are_the_turning_wrist_carrying_their_relative_poses) {
    WristGlove glove(turning_wrist(), two_fingers());
    const std::vector<Keyframes> rel = two_fingers();
    Playback wrist(motion(Vec3(0.1, 0.2, 0.3), turn(Vec3(0, 0, 1), 0.2), Vec3(0.2, 0.2, 0.3), turn(kAxis, kPi / 2)),
                   1e300);
    CHECK(glove.frames() == 3);
    Pose out[3], w;
    for (double t : {0.0, 0.25, 0.5, 0.9, 1.0}) {
        CHECK(glove.read_frames(t, out, 3) && wrist.read(t, w));
        CHECK((out[0].position - w.position).norm() == 0 && (out[0].quaternion - w.quaternion).norm() == 0);
        for (int b = 1; b < 3; ++b) {
            const Pose r = rel[b - 1].at(t);
            const Vec3 p = w.position + rotate(w.quaternion, r.position);
            const Vec4 q = quat_multiply(w.quaternion, r.quaternion);
            CHECK_LT((out[b].position - p).norm(), 1e-12);
            CHECK_LT(std::min((out[b].quaternion - q).norm(), (out[b].quaternion + q).norm()), 1e-12);
        }
    }
    // the frames move as the wrist turns: finger 2 travels centimetres, so the check can fail
    Pose a[3], b[3];
    CHECK(glove.read_frames(0.0, a, 3) && glove.read_frames(1.0, b, 3));
    CHECK((b[2].position - a[2].position - (b[0].position - a[0].position)).norm() > 0.02);
}

TEST(finger_velocities_are_central_differences_of_the_frames) {
    WristGlove glove(turning_wrist(), two_fingers());
    const double h = 1e-6;
    for (double t : {0.2, 0.5, 0.8}) {
        Pose now[3], before[3], after[3];
        CHECK(glove.read_frames(t, now, 3) && glove.read_frames(t - h, before, 3) && glove.read_frames(t + h, after, 3));
        for (int b = 0; b < 3; ++b) {
            const Vec3 v = (after[b].position - before[b].position) / (2 * h);
            // world-frame angular velocity: the turn from t - h to t + h over 2h
            const Vec3 w = quat_to_rotation_vector(quat_multiply(after[b].quaternion,
                                                                 quat_conjugate(before[b].quaternion))) / (2 * h);
            CHECK(now[b].velocity.norm() > 0.05 && now[b].angular_velocity.norm() > 1.0);  // moving and turning
            CHECK_LT((now[b].velocity - v).norm(), 1e-6 * now[b].velocity.norm());
            CHECK_LT((now[b].angular_velocity - w).norm(), 1e-6 * now[b].angular_velocity.norm());
        }
    }
}

TEST(the_wrist_is_commanded_the_whole_hands_wrench_about_its_point) {
    auto held = std::make_unique<Held>();
    Held& device = *held;
    WristGlove glove(std::move(held), still_fingers());
    Pose out[3];
    CHECK(glove.read_frames(0.5, out, 3));
    // turned 90 degrees about z: finger 1 sits 10 cm along world y, finger 2 5 cm along world z
    CHECK_LT((out[1].position - Vec3(0.3, 0.1, 0.1)).norm(), 1e-15);
    CHECK_LT((out[2].position - Vec3(0.3, 0, 0.15)).norm(), 1e-15);
    const Feedback bones[3] = {wrench(Vec3(1, 0, 0), Vec3(0, 0.01, 0)), wrench(Vec3(0, 0, 2), Vec3(0, 0, 0.05)),
                               wrench(Vec3(3, 0, 0), Vec3::Zero())};
    glove.command_frames(bones, 3, nullptr, 0);
    // forces 1 + 2 + 3; torques 0.01 y + 0.05 z, plus (0, 0.1, 0) x (0, 0, 2) = (0.2, 0, 0)
    // and (0, 0, 0.05) x (3, 0, 0) = (0, 0.15, 0)
    CHECK_LT((device.got.force - Vec3(4, 0, 2)).norm(), 1e-15);
    CHECK_LT((device.got.torque - Vec3(0.2, 0.16, 0.05)).norm(), 1e-15);
    CHECK((glove.commanded().force - device.got.force).norm() == 0);
}

TEST(the_clamp_applies_to_the_summed_wrench) {
    auto held = std::make_unique<Held>();
    held->max_force = 2;   // each bone's force is below it, their sum is not
    held->max_torque = 0.1;
    Held& device = *held;
    WristGlove glove(std::move(held), still_fingers());
    CHECK(glove.max_force == 2 && glove.max_torque == 0.1);
    Pose out[3];
    CHECK(glove.read_frames(0.5, out, 3));
    const Feedback bones[3] = {wrench(Vec3(1, 0, 0), Vec3::Zero()), wrench(Vec3(0, 0, 1.5), Vec3::Zero()),
                               wrench(Vec3(1.5, 0, 0), Vec3::Zero())};
    glove.command_frames(bones, 3, nullptr, 0);
    const Vec3 sum(2.5, 0, 1.5), moment = Vec3(0, 0.1, 0).cross(Vec3(0, 0, 1.5)) + Vec3(0, 0, 0.05).cross(Vec3(1.5, 0, 0));
    CHECK_LT((device.got.force - 2 * sum / sum.norm()).norm(), 1e-15);
    CHECK_LT((device.got.torque - 0.1 * moment / moment.norm()).norm(), 1e-15);
}

TEST(a_failing_wrist_fails_the_glove_with_its_message) {
    WristGlove glove(turning_wrist(0.3), two_fingers());
    Pose out[3];
    CHECK(glove.read_frames(0.2, out, 3));
    CHECK(!glove.read_frames(0.3, out, 3));
    CHECK(std::string(glove.error()).find("the playback device was told to disconnect (t = 0.300 s)") !=
          std::string::npos);
    CHECK(!glove.read(0.1, out[0]));  // one frame of it is not a pose: the session reads its frames
}

TEST(reading_and_commanding_allocate_nothing) {
    WristGlove glove(turning_wrist(), two_fingers());
    Pose out[3];
    Feedback bones[3];
    const long before = g_allocations.load();
    bool ok = true;
    for (int i = 0; i < 1000; ++i) {
        ok = ok && glove.read_frames(1e-3 * i, out, 3);
        bones[2].force = Vec3(0, 0, 1e-3 * i);
        glove.command_frames(bones, 3, nullptr, 0);
    }
    CHECK(ok);
    CHECK(!kCountsAllocations || g_allocations.load() - before == 0);
}
