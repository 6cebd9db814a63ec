#include "haptics/session.h"
#include "params/table.h"

#include <sys/prctl.h>
#include <time.h>

#include <chrono>
#include <cmath>
#include <cstring>

#include "common/clock.h"
#include "haptics/realtime.h"
#include "haptics/session_bones.h"
#include "sim/world.h"

namespace hh {

namespace {
double wall_now() { return wall_seconds(); }

Body& hand_body(World& world, int hand) {
    if (hand < 0 || hand >= static_cast<int>(world.bodies.size()) || world.bodies[hand]->kind != BodyKind::Hand)
        throw InvalidArgument("a haptic session needs the hand's body index");
    return *world.bodies[hand];
}

CouplingModel resting_model(World& world, int hand) {
    const HandleState& h = hand_body(world, hand).hand->h;
    CouplingModel m;  // not valid: no visual step has been linearized yet
    m.time = 0;
    m.x_h = h.x_com;
    m.q_h = h.q;
    return m;
}

ProxySample first_sample(World& world, int hand) {
    ProxySample s;
    s.proxy = hand_body(world, hand).hand->h;
    s.device.position = s.proxy.x_com;
    s.device.quaternion = s.proxy.q;
    return s;
}

Frame empty_frame(World& world, int hand) {
    Frame f;
    std::size_t vertices = 0;
    for (const auto& b : world.bodies)
        if (b->has_surface) vertices += b->surface.n_vertices();
    f.surfaces.assign(3 * vertices, 0.0);
    f.poses.assign(7 * world.bodies.size(), 0.0);
    if (hand_body(world, hand).skeleton()) {
        const std::size_t nb = hand_body(world, hand).hand_model->n_bones();
        for (std::vector<double>* v : {&f.bone_handles, &f.bone_proxies, &f.bone_devices}) v->assign(7 * nb, 0.0);
        for (std::vector<double>* v : {&f.bone_feedback, &f.group_feedback, &f.bone_wrench}) v->assign(6 * nb, 0.0);
        f.bone_stiffness.assign(36 * nb * nb, 0.0);
    }
    return f;
}

// The ranges of every field are the table's (checked at the C entry points); what holds
// between fields is checked here: the coupling's passivity at the loop's rate.
void check_params(const SessionParams& p) { check_passive(p.coupling, p.haptic_rate); }
}  // namespace

SessionParams::SessionParams() : SessionParams(params::session_defaults()) {}

SessionParams::SessionParams(const hh_session_params& p)
    : haptic_rate(p.haptic_rate),
      coupling(p.coupling_stiffness, p.coupling_damping, p.coupling_angular_stiffness, p.coupling_angular_damping),
      max_force(p.max_force),
      max_torque(p.max_torque),
      linearized(p.linearized != 0),
      log_capacity(static_cast<std::size_t>(p.log_capacity)),
      realtime(p.realtime != 0) {}

Session::Session(World& world, int hand, const SessionParams& params)
    : world_(world),
      hand_(hand),
      p_((check_params(params), params)),
      models_(resting_model(world, hand)),
      samples_(first_sample(world, hand)),
      frames_(empty_frame(world, hand)),
      log_(params.log_capacity) {
    Body& b = hand_body(world, hand);
    proxy_.mass = b.hand_model->handle.mass;
    proxy_.inertia_body = b.hand_model->handle.inertia_body;
    proxy_.state = b.hand->h;
    sample_ = first_sample(world, hand);
    // Without linearization the visual loop couples the handle to the device itself, with
    // the session's gains.
    hh_params& mp = b.hand_model->params;
    mp.coupling_stiffness = p_.coupling.stiffness;
    mp.coupling_damping = p_.coupling.damping;
    mp.coupling_angular_stiffness = p_.coupling.angular_stiffness;
    mp.coupling_angular_damping = p_.coupling.angular_damping;
    int offset = 0;
    for (const auto& body : world.bodies) {
        surface_offset_.push_back(body->has_surface ? offset : -1);
        if (body->has_surface) offset += body->surface.n_vertices();
    }
    if (b.skeleton()) bones_ = std::make_unique<Bones>(*b.hand_model, *b.hand, p_.coupling, 1.0 / p_.haptic_rate);
    t_haptic_ = world.time;
    set_clock_rate(p_.haptic_rate);
    publish_frame();
}

Session::~Session() { stop(); }

void Session::set_clock_rate(double rate) {
    rate_ = rate;
    dt_haptic_ = 1.0 / rate;
    clock_origin_ = t_haptic_;
    clock_steps_ = 0;
    if (bones_) bones_->publish_model(dt_haptic_);  // (the proxies' step matrix is the period's)
}

double Session::advance_clock() {
    // from the step count, not by adding periods: step n is at exactly origin + n / rate
    ++clock_steps_;
    t_haptic_ = clock_origin_ + static_cast<double>(clock_steps_) / rate_;
    return t_haptic_;
}

void Session::set_device(std::unique_ptr<Device> device) {
    if (running()) throw InvalidArgument("stop the session before changing its device");
    if (device && bones_ && device->frames() == 1 && !posed_fingers_.empty()) device = wrap_wrist(std::move(device));
    if (device && device->frames() != n_bones())
        throw InvalidArgument(bones_ ? "this session's hand has " + std::to_string(n_bones()) +
                                           " bones: give it a device of one frame per bone (an external glove or "
                                           "the simulated glove), or pose its fingers (hh_session_pose_fingers) "
                                           "for a one-frame device on the wrist"
                                     : std::string("this session's hand has one handle: a glove of ") +
                                           std::to_string(device->frames()) +
                                           " frames drives a skeleton hand's session; give it a one-frame device");
    device_ = std::move(device);
    wrist_ = dynamic_cast<WristGlove*>(device_.get());
    Device* one = wrist_ ? &wrist_->wrist() : device_.get();  // the host pushes the wrist's pose
    external_ = dynamic_cast<ExternalDevice*>(one);
    external_frames_ = dynamic_cast<ExternalFrames*>(device_.get());
}

std::unique_ptr<Device> Session::wrap_wrist(std::unique_ptr<Device> device) {
    auto glove = std::make_unique<WristGlove>(std::move(device), posed_fingers_);
    // the summed wrench is clamped to the session's limits and the wrist device's
    glove->max_force = std::min(glove->max_force, p_.max_force);
    glove->max_torque = std::min(glove->max_torque, p_.max_torque);
    return glove;
}

void Session::pose_fingers(std::vector<Keyframes> fingers) {
    if (running()) throw InvalidArgument("stop the session before posing its fingers");
    if (!bones_)
        throw InvalidArgument("this session's hand has one handle: posed fingers ride on a skeleton hand's root");
    if (bones_->groups.n() > 0)
        throw InvalidArgument("this session has feedback groups, which need a glove of one frame per bone: a "
                              "one-frame wrist device renders one wrench, the whole hand's; clear the groups "
                              "(hh_session_set_feedback_groups with 0 groups) to pose the fingers");
    if (static_cast<int>(fingers.size()) != n_bones() - 1)
        throw InvalidArgument("the posed fingers need one script per bone but the root: the hand has " +
                              std::to_string(n_bones()) + " bones");
    posed_fingers_ = std::move(fingers);
    if (wrist_) {
        std::unique_ptr<Device> wrist = wrist_->release_wrist();
        device_.reset();
        wrist_ = nullptr;
        set_device(std::move(wrist));
    }
}

Pose Session::handle_pose() const {
    const HandleState& h = world_.bodies[hand_]->hand->h;
    Pose p;
    p.position = h.x_com;
    p.quaternion = h.q;
    return p;
}

void Session::fail(const char* message) noexcept {
    static_assert(sizeof(message_) > 1, "message buffer");
    bool expected = false;
    if (!failing_.compare_exchange_strong(expected, true)) return;  // the first failure is the one reported
    std::snprintf(message_, sizeof message_, "%s", message ? message : "unknown failure");
    failed_.store(true, std::memory_order_release);
}

bool Session::haptic_step(double t) noexcept {
    const double start = wall_now();
    if (bones_) return bones_haptic_step(t, start);
    models_.fetch();
    const CouplingModel& model = models_.front();
    Pose dev;
    if (!device_->read(t, dev)) {
        fail(device_->error());
        return false;
    }
    Feedback fb = proxy_.step(dt_haptic_, t - dt_haptic_, model, p_.linearized, dev, p_.coupling);
    if (!limit_feedback(fb)) return false;
    device_->command(fb);

    ProxySample& s = samples_.back();
    s.time = t;
    s.proxy = proxy_.state;
    s.device = dev;
    s.feedback = fb;
    samples_.publish();

    log_step(t, start, dev, proxy_.state, fb);
    return true;
}

bool Session::limit_feedback(Feedback& fb, bool clamp) noexcept {
    const double f_max = std::min(p_.max_force, device_->max_force);
    const double t_max = std::min(p_.max_torque, device_->max_torque);
    const double fn = fb.force.norm(), tn = fb.torque.norm();
    if (!(std::isfinite(fn) && std::isfinite(tn))) {
        fail("the haptic step produced a non-finite force: lower the virtual coupling stiffness or check the device");
        return false;
    }
    if (!clamp) return true;
    if (fn > f_max) fb.force *= f_max / fn;
    if (tn > t_max) fb.torque *= t_max / tn;
    return true;
}

void Session::log_step(double t, double start, const Pose& dev, const HandleState& proxy, const Feedback& fb) noexcept {
    LogRow row;
    row.v[0] = t;
    row.v[1] = live_ ? (last_tick_wall_ < 0 ? dt_haptic_ : start - last_tick_wall_) : dt_haptic_;
    put_pose(row.v + 3, dev.position, dev.quaternion);
    put_pose(row.v + 10, proxy.x_com, proxy.q);
    for (int i = 0; i < 3; ++i) {
        row.v[17 + i] = fb.force[i];
        row.v[20 + i] = fb.torque[i];
    }
    last_tick_wall_ = start;
    row.v[2] = wall_now() - start;
    log_.push(row);
    haptic_steps_.fetch_add(1, std::memory_order_release);
}

void Session::visual_step() {
    if (bones_) {
        bones_visual_step();
        return;
    }
    if (samples_.fetch()) sample_ = samples_.front();
    Body& b = *world_.bodies[hand_];
    DeviceFrame& d = b.hand->device;
    d.enabled = true;
    if (p_.linearized) {
        // the visual loop's handle is driven to the proxy (Section 3)
        d.prescribed = true;
        d.position = sample_.proxy.x_com;
        d.quaternion = sample_.proxy.q;
        d.velocity = sample_.proxy.v_com;
        d.angular_velocity = sample_.proxy.omega;
    } else {
        // no linearization: the handle follows the device through the virtual coupling (Fig. 2 top)
        d.prescribed = false;
        d.position = sample_.device.position;
        d.quaternion = sample_.device.quaternion;
        d.velocity = sample_.device.velocity;
        d.angular_velocity = sample_.device.angular_velocity;
    }
    world_.step();
    CouplingModel& m = models_.back();
    if (p_.linearized) {
        m = linearize_coupling(world_, hand_);
        // The reference the model measures the proxy's displacement from: the handle's motion
        // continued from this step. The step's velocity is its average over the step; with the
        // previous step's it gives the acceleration, and the velocity at the step's end. In free
        // space the reference keeps accelerating (else the model's stiffness, mostly the flesh's
        // mass over dt^2, would add to the inertia the user feels); in contact it does not (a
        // wall stops a hand, it does not keep decelerating it).
        const double dt = world_.settings.dt;
        const Vec3 v_step = m.v_h, w_step = m.omega_h;
        if (have_previous_step_ && m.held_rows == 0) {
            m.a_h = (v_step - previous_v_) / dt;
            m.alpha_h = (w_step - previous_omega_) / dt;
            m.v_h = v_step + 0.5 * dt * m.a_h;
            m.omega_h = w_step + 0.5 * dt * m.alpha_h;
        }
        previous_v_ = v_step;
        previous_omega_ = w_step;
        have_previous_step_ = true;
    } else {
        m = CouplingModel{};
        const HandleState& h = b.hand->h;
        m.x_h = h.x_com;
        m.q_h = h.q;
        m.v_h = h.v_com;
        m.omega_h = h.omega;
    }
    m.time = sample_.time;
    m.horizon = 2 * world_.settings.dt;
    models_.publish();
    visual_steps_.fetch_add(1, std::memory_order_release);
    publish_frame();
}

void Session::publish_frame() {
    Frame& f = frames_.back();
    f.time = world_.time;
    f.visual_steps = visual_steps();
    for (std::size_t i = 0; i < world_.bodies.size(); ++i) {
        const Body& b = *world_.bodies[i];
        if (surface_offset_[i] >= 0) {
            double* out = f.surfaces.data() + 3 * surface_offset_[i];
            for (int v = 0; v < b.surface.n_vertices(); ++v)
                for (int k = 0; k < 3; ++k) out[3 * v + k] = b.surface.x[v][k];
        }
        if (b.kind == BodyKind::Rigid || b.kind == BodyKind::Kinematic || b.kind == BodyKind::Static)
            put_pose(f.poses.data() + 7 * i, b.mesh.state.x_com, b.mesh.state.q);
    }
    const HandleState& h = world_.bodies[hand_]->hand->h;
    put_pose(f.handle, h.x_com, h.q);
    put_pose(f.proxy, sample_.proxy.x_com, sample_.proxy.q);
    put_pose(f.device, sample_.device.position, sample_.device.quaternion);
    for (int i = 0; i < 3; ++i) {
        f.feedback[i] = sample_.feedback.force[i];
        f.feedback[3 + i] = sample_.feedback.torque[i];
    }
    const CouplingModel& m = models_.back();  // what the visual loop just published (it keeps a copy)
    for (int i = 0; i < 6; ++i) {
        f.wrench[i] = m.wrench[i];
        for (int j = 0; j < 6; ++j) f.stiffness[6 * i + j] = m.stiffness(i, j);
    }
    f.held_rows = m.held_rows;
    f.contacts = world_.stats.contacts;
    if (bones_) bones_publish_frame(f);
    frames_.publish();
}

void Session::run_offline(int visual_steps) {
    if (!device_) throw InvalidArgument("the session has no device: choose one before running it");
    if (running()) throw InvalidArgument("the session is running live: stop it before stepping it offline");
    if (failed()) throw InvalidArgument(std::string("the session has stopped: ") + message_);
    live_ = false;
    // the haptic clock runs at the session's rate, from where the world is (a live run or steps
    // of the world without the session may have left it elsewhere)
    if (rate_ != p_.haptic_rate || world_.time - t_haptic_ > dt_haptic_ || t_haptic_ - world_.time > dt_haptic_) {
        t_haptic_ = world_.time;
        set_clock_rate(p_.haptic_rate);
    }
    for (int k = 0; k < visual_steps; ++k) {
        // Every haptic step due by the end of this visual step, at exact multiples of the period:
        // the rest of a period carries over to the next frame (a 1/30 s frame takes 33 or 34 at
        // 1 kHz), so the log is what a 1 kHz device sees. 1e-6 of a period absorbs the round-off
        // of the world's clock, which adds dt every step.
        const double end = world_.time + world_.settings.dt;
        const double due = std::floor((end - clock_origin_) * rate_ + 1e-6);
        while (static_cast<double>(clock_steps_) < due)
            if (!haptic_step(advance_clock())) throw InvalidArgument(std::string("the session stopped: ") + message_);
        visual_step();
    }
}

void Session::haptic_thread() noexcept {
    // a 1 ms period needs wake-ups far finer than Linux's default 50 us timer slack
    prctl(PR_SET_TIMERSLACK, 1000UL, 0, 0, 0);
    // Real-time priority when allowed (root, CAP_SYS_NICE or an rtprio limit): on a loaded
    // machine an ordinary thread waits behind others for milliseconds. It sleeps 90% of each
    // period, so it cannot starve the machine; without the permission it runs as an ordinary
    // thread. Then a CPU of its own and its memory locked: what the loop touches is in RAM before
    // the first deadline, so the loop takes no page fault (docs/haptics.md, "Timing").
    const MemoryRange ranges[2] = {{this, sizeof *this}, {log_.storage(), log_.storage_bytes()}};
    double (*const atan2_of)(double, double) = &std::atan2;
    const void* const code[3] = {reinterpret_cast<const void*>(&check_passive), reinterpret_cast<const void*>(atan2_of),
                                 reinterpret_cast<const void*>(&clock_nanosleep)};
    loop_ = set_up_loop_thread(p_.realtime, kHapticPriority, kHapticStackBytes, ranges, 2, code, 3);
    realtime_.store(loop_.priority, std::memory_order_release);
    // The clock once before the count: the loop's one page fault, seen by perf in some runs, was
    // its first clock_gettime, in the vDSO
    timespec warm{};
    clock_gettime(CLOCK_MONOTONIC, &warm);
    double minor0, major0;
    thread_page_faults(minor0, major0);
    // Sleep to just before the deadline (an absolute one: no drift), then spin the last stretch:
    // the kernel's wake-up latency (tens of microseconds, more on a busy machine) lands inside
    // the spin instead of on the period. Costs about 8% of a core at 1 kHz.
    const std::int64_t period = std::llround(dt_haptic_ * 1e9), spin = 80000;  // ns
    timespec now{};
    clock_gettime(CLOCK_MONOTONIC, &now);
    std::int64_t next = now.tv_sec * 1000000000LL + now.tv_nsec;
    while (!stop_.load(std::memory_order_acquire) && !failed()) {
        next += period;
        const std::int64_t wake = next - spin;
        const timespec until{static_cast<time_t>(wake / 1000000000LL), static_cast<long>(wake % 1000000000LL)};
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &until, nullptr);
        do clock_gettime(CLOCK_MONOTONIC, &now);
        while (now.tv_sec * 1000000000LL + now.tv_nsec < next);
        if (!haptic_step(advance_clock())) break;
    }
    double minor1, major1;
    thread_page_faults(minor1, major1);
    loop_minor_faults_ = minor1 - minor0;
    loop_major_faults_ = major1 - major0;
    release_loop_memory(loop_, ranges, 2);
}

void Session::visual_thread() noexcept {
    try {
        const double start = wall_now();
        const double sim_start = world_.time;
        while (!stop_.load(std::memory_order_acquire) && !failed()) {
            // A step ends at world time t + dt and drives the handle to the proxy: wait until the
            // wall clock gets there, so that the proxy it reads is the one at t + dt, as offline
            // (run_offline) and in a bake of the same recording. Waiting before the step rather
            // than after it shows each frame just as late (by the step's cost), and labels it right.
            const double ahead = (world_.time + world_.settings.dt - sim_start) - (wall_now() - start);
            if (ahead > 0) std::this_thread::sleep_for(std::chrono::duration<double>(ahead));
            if (stop_.load(std::memory_order_acquire) || failed()) break;
            visual_step();
        }
    } catch (const std::exception& e) {
        fail((std::string("the visual loop stopped: ") + e.what()).c_str());
    } catch (...) {
        fail("the visual loop stopped: unknown error");
    }
}

namespace {
void servo_tick(void* user) {
    auto* s = static_cast<Session*>(user);
    s->servo_step();
}
}  // namespace

void Session::servo_step() noexcept {
    if (stop_.load(std::memory_order_acquire) || failed()) return;
    haptic_step(advance_clock());
}

void Session::start() {
    if (!device_) throw InvalidArgument("the session has no device: choose one before starting it");
    if (running()) return;
    if (failed()) throw InvalidArgument(std::string("the session has stopped: ") + message_);
    live_ = true;
    stop_.store(false, std::memory_order_release);
    last_tick_wall_ = -1;
    if (device_->has_servo_loop()) {
        check_passive(p_.coupling, 1000);  // the driver's servo loop runs at 1 kHz
        set_clock_rate(1000);
        device_->start_servo(&servo_tick, this);
    } else {
        set_clock_rate(p_.haptic_rate);
        haptic_thread_ = std::thread(&Session::haptic_thread, this);
    }
    visual_thread_ = std::thread(&Session::visual_thread, this);
    running_.store(true, std::memory_order_release);
}

void Session::stop() noexcept {
    stop_.store(true, std::memory_order_release);
    if (haptic_thread_.joinable()) haptic_thread_.join();
    if (device_ && device_->has_servo_loop()) device_->stop_servo();
    if (visual_thread_.joinable()) visual_thread_.join();
    running_.store(false, std::memory_order_release);
}

}  // namespace hh
