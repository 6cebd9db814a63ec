// A haptic session on a skeleton hand (docs/skeleton.md, Section 6; haptics/session_bones.h): the
// visual loop drives every bone to its proxy and publishes the bones' model with its contacts
// held; the haptic loop reads one device frame per bone, steps the B proxies against the model
// and commands the feedback per bone and per group. The palm handle's session (haptics/session.cpp)
// never comes here.
#include "haptics/session_bones.h"

#include "common/clock.h"
#include "sim/world.h"

namespace hh {

BoneCouplingModel resting_bone_model(const Data& d, int n_bones) {
    BoneCouplingModel m;  // not valid: the proxies feel no model
    for (int b = 0; b < n_bones; ++b) m.ends.push_back(bone_state(d, b));
    m.accelerations.assign(n_bones, Vec6::Zero());
    m.wrench = VecX::Zero(6 * n_bones);
    m.stiffness = MatX::Zero(6 * n_bones, 6 * n_bones);
    return m;
}

namespace {
std::vector<HandleState> bone_states(const Data& d, int n) {
    std::vector<HandleState> out;
    for (int b = 0; b < n; ++b) out.push_back(bone_state(d, b));
    return out;
}

BoneSample first_sample(const Data& d, int n) {
    BoneSample s;
    s.proxies = bone_states(d, n);
    for (const HandleState& h : s.proxies) {
        Pose p;
        p.position = h.x_com;
        p.quaternion = h.q;
        s.devices.push_back(p);
    }
    s.feedback.assign(n, Feedback{});
    s.groups.assign(n, Feedback{});
    return s;
}
}  // namespace

Session::Bones::Bones(const Model& m, const Data& d, const VirtualCoupling& coupling, double h)
    : n(m.n_bones()),
      proxies(m, bone_states(d, m.n_bones()), coupling),
      samples(first_sample(d, m.n_bones())),
      groups(std::vector<int>(m.n_bones(), -1), 0),
      devices(first_sample(d, m.n_bones()).devices),
      feedback(m.n_bones()),
      group_out(m.n_bones()),
      sample(first_sample(d, m.n_bones())),
      last_model(resting_bone_model(d, m.n_bones())) {
    publish_model(h);
}

void Session::Bones::publish_model(double h) {
    BoneSnapshot& s = models.back();
    s.model = last_model;
    proxies.prepare(s, h);
    models.publish();
}

int Session::n_bones() const { return bones_ ? bones_->n : 1; }

std::vector<Pose> Session::bone_poses() const {
    return first_sample(*world_.bodies[hand_]->hand, n_bones()).devices;
}
int Session::n_groups() const { return bones_ ? bones_->groups.n() : 0; }

void Session::set_feedback_groups(const FeedbackGroups& groups) {
    if (running()) throw InvalidArgument("stop the session before changing its feedback groups");
    if (!bones_)
        throw InvalidArgument("this session's hand has one handle: feedback groups sum the bones of a skeleton hand");
    if (static_cast<int>(groups.of_bone.size()) != bones_->n || groups.n() > bones_->n)
        throw InvalidArgument("the feedback groups need one group (or -1) per bone: the hand has " +
                              std::to_string(bones_->n) + " bones, and at most as many groups");
    bones_->groups = groups;
}

bool Session::bones_haptic_step(double t, double start) noexcept {
    Bones& s = *bones_;
    s.models.fetch();
    if (!device_->read_frames(t, s.devices.data(), s.n)) {
        fail(device_->error());
        return false;
    }
    s.proxies.step(dt_haptic_, t - dt_haptic_, s.models.front(), p_.linearized, s.devices.data(), s.feedback.data());
    // A wrist glove clamps the whole hand's wrench it sums (device/wrist_glove.h), not each bone's:
    // a squeeze inside the hand, each finger over the device's limit, sums to no force on the stylus.
    for (Feedback& fb : s.feedback)
        if (!limit_feedback(fb, wrist_ == nullptr)) return false;
    group_feedback(s.groups, s.devices.data(), s.feedback.data(), s.group_out.data());
    for (int g = 0; g < s.groups.n(); ++g)
        if (!limit_feedback(s.group_out[g])) return false;
    device_->command_frames(s.feedback.data(), s.n, s.group_out.data(), s.groups.n());

    BoneSample& out = s.samples.back();
    out.time = t;
    for (int b = 0; b < s.n; ++b) {
        out.proxies[b] = s.proxies.state[b];
        out.devices[b] = s.devices[b];
        out.feedback[b] = s.feedback[b];
    }
    for (int g = 0; g < s.groups.n(); ++g) out.groups[g] = s.group_out[g];
    // the log and the palm fields hold what the device felt: a wrist glove's whole-hand wrench
    out.commanded = wrist_ ? wrist_->commanded() : s.feedback[0];
    s.samples.publish();
    log_step(t, start, s.devices[0], s.proxies.state[0], out.commanded);
    return true;
}

void Session::bones_visual_step() {
    Bones& s = *bones_;
    if (s.samples.fetch()) s.sample = s.samples.front();
    Data& d = *world_.bodies[hand_]->hand;
    for (int b = 0; b < s.n; ++b) {
        DeviceFrame& target = bone_target(d, b);
        target.enabled = true;
        // linearized: every bone driven to its proxy (Section 3); else each follows its device
        // frame through its virtual coupling (Fig. 2 top)
        target.prescribed = p_.linearized;
        const HandleState& proxy = s.sample.proxies[b];
        const Pose& device = s.sample.devices[b];
        target.position = p_.linearized ? proxy.x_com : device.position;
        target.quaternion = p_.linearized ? proxy.q : device.quaternion;
        target.velocity = p_.linearized ? proxy.v_com : device.velocity;
        target.angular_velocity = p_.linearized ? proxy.omega : device.angular_velocity;
    }
    world_.step();
    BoneCouplingModel& m = s.last_model;
    m = p_.linearized ? linearize_bone_coupling(world_, hand_) : resting_bone_model(d, s.n);
    if (p_.linearized && m.held_rows > 0) {
        // Each bone's reference motion continued from this step: in free space at its velocity; in
        // contact not at all: a contact stops a bone pressed into it. (Continued at the step's
        // velocity in contact, a finger's light proxy followed its reference into the ground: the
        // gripper's fingers pressed by the simulated glove bounced at ~7 Hz, 0.5-2 mm deep, feeling
        // 0.1-2 N against the world's 50-140 N. Continued with the acceleration of the last two
        // steps as well, as the palm handle's, a light finger's proxy on a soft glove finger fed
        // its own motion back: the two-finger hand closing in free space at haptics.glove.*'s
        // defaults swung its bones' springs' force between 0.03 and 11 N from frame to frame, and
        // lifting the ball the haptic step's force became non-finite.)
        for (HandleState& end : m.ends) {
            end.v_com.setZero();
            end.omega.setZero();
        }
    }
    m.time = s.sample.time;
    m.horizon = 2 * world_.settings.dt;
    s.publish_model(dt_haptic_);
    visual_steps_.fetch_add(1, std::memory_order_release);
    publish_frame();
}

void Session::bones_publish_frame(Frame& f) {
    const Bones& s = *bones_;
    const Data& d = *world_.bodies[hand_]->hand;
    for (int b = 0; b < s.n; ++b) {
        const HandleState& h = bone_state(d, b);
        put_pose(f.bone_handles.data() + 7 * b, h.x_com, h.q);
        put_pose(f.bone_proxies.data() + 7 * b, s.sample.proxies[b].x_com, s.sample.proxies[b].q);
        put_pose(f.bone_devices.data() + 7 * b, s.sample.devices[b].position, s.sample.devices[b].quaternion);
        Eigen::Map<Vec3>(f.bone_feedback.data() + 6 * b) = s.sample.feedback[b].force;
        Eigen::Map<Vec3>(f.bone_feedback.data() + 6 * b + 3) = s.sample.feedback[b].torque;
        Eigen::Map<Vec3>(f.group_feedback.data() + 6 * b) = s.sample.groups[b].force;
        Eigen::Map<Vec3>(f.group_feedback.data() + 6 * b + 3) = s.sample.groups[b].torque;
    }
    const int nh = 6 * s.n;
    Eigen::Map<VecX>(f.bone_wrench.data(), nh) = s.last_model.wrench;
    Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(f.bone_stiffness.data(), nh, nh) =
        s.last_model.stiffness;
    // the root's in the palm handle's fields
    put_pose(f.proxy, s.sample.proxies[0].x_com, s.sample.proxies[0].q);
    put_pose(f.device, s.sample.devices[0].position, s.sample.devices[0].quaternion);
    Eigen::Map<Vec3>(f.feedback) = s.sample.commanded.force;
    Eigen::Map<Vec3>(f.feedback + 3) = s.sample.commanded.torque;
    for (int i = 0; i < 6; ++i) {
        f.wrench[i] = s.last_model.wrench[i];
        for (int j = 0; j < 6; ++j) f.stiffness[6 * i + j] = s.last_model.stiffness(i, j);
    }
    f.held_rows = s.last_model.held_rows;
}

}  // namespace hh
