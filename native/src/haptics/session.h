// A haptic session: the visual loop (contact simulation of the world, handle driven to the
// proxy, coupling model) and the haptic loop (proxy handle, virtual coupling, device), with
// the two clocks of the ARCHITECTURE:
//   live:    two threads paced by the wall clock (or the device driver's servo loop for the
//            haptic side); they exchange only immutable snapshots through triple buffers;
//   offline: the same steps in virtual time, the haptic steps in lockstep between visual
//            steps, so a run is reproducible bit for bit.
// The haptic step never allocates, never waits on a lock and never calls Python.
#pragma once
#include <atomic>
#include <cstdint>
#include <memory>
#include <thread>
#include <vector>

#include "haptic_hand.h"
#include "device/device.h"
#include "device/external.h"
#include "device/external_frames.h"
#include "device/wrist_glove.h"
#include "haptics/bone_proxies.h"
#include "haptics/coupling_model.h"
#include "haptics/haptic_log.h"
#include "haptics/proxy.h"
#include "haptics/realtime.h"
#include "common/triple_buffer.h"

namespace hh {

class World;

// The haptic loop's settings: the hh_session_params rows of the parameter table (meanings and
// ranges there), checked by the C entry points against it.
struct SessionParams {
    SessionParams();  // the table's defaults
    explicit SessionParams(const hh_session_params& p);
    double haptic_rate;        // Hz
    VirtualCoupling coupling;  // two-way, device <-> proxy (and device -> handle without linearization)
    double max_force;          // N: feedback clamp (the device's own limit applies too)
    double max_torque;         // N m
    bool linearized;           // false: feedback from the last visual-loop handle only
    std::size_t log_capacity;  // rows: the host reads them as they come
    bool realtime;             // live: ask for SCHED_FIFO for the haptic thread (needs CAP_SYS_NICE)
};

// What the haptic loop tells the visual loop: the proxy, where the device is.
struct ProxySample {
    double time = 0;
    HandleState proxy;
    Pose device;
    Feedback feedback;
};

// What the visual loop shows: every body's collision-surface vertices and poses, the handle,
// proxy, device and feedback of the step. Sized once at the start.
struct Frame {
    double time = 0;
    std::uint64_t visual_steps = 0;
    std::vector<double> surfaces;  // xyz of each body's surface vertices, bodies in order
    std::vector<double> poses;     // 7 per body: centre and quaternion (rigid, kinematic, static)
    double handle[7] = {0, 0, 0, 0, 0, 0, 1};
    double proxy[7] = {0, 0, 0, 0, 0, 0, 1};
    double device[7] = {0, 0, 0, 0, 0, 0, 1};
    double feedback[6] = {0, 0, 0, 0, 0, 0};
    double wrench[6] = {0, 0, 0, 0, 0, 0};  // F_c0 of the coupling model
    double stiffness[36] = {0};              // its dF_c/d(dx, dtheta), row-major
    int contacts = 0;
    int held_rows = 0;
    // A skeleton hand's session (haptics/session_bones.cpp), else empty: per bone its pose,
    // proxy and device frame (7 each: position, quaternion) and its feedback (6); per group
    // (up to one per bone) its feedback (6); the bones' model (wrench 6B, stiffness 6B x 6B
    // row-major). The root's are also in the palm fields above.
    std::vector<double> bone_handles, bone_proxies, bone_devices, bone_feedback, group_feedback;
    std::vector<double> bone_wrench, bone_stiffness;
};

class Session {
public:
    static constexpr int kHapticPriority = 80;                   // SCHED_FIFO, below the kernel's own threads (99)
    static constexpr std::size_t kHapticStackBytes = 128 << 10;  // of the haptic thread, faulted in and locked

    Session(World& world, int hand, const SessionParams& params);
    ~Session();
    Session(const Session&) = delete;
    Session& operator=(const Session&) = delete;

    // Throws InvalidArgument unless the device has one frame per bone (one: the palm handle), or
    // is a one-frame device on a skeleton hand whose fingers are posed (pose_fingers): that one
    // is wrapped in a WristGlove (device/wrist_glove.h), the wrist's device feeling the whole hand.
    void set_device(std::unique_ptr<Device> device);
    // A skeleton hand's bones 1 .. B-1 posed relative to the root (fingers[b - 1]: T_root^-1 T_b
    // over time, set while stopped): a one-frame device then drives the root and carries them.
    // A wrist glove already attached takes the new poses.
    void pose_fingers(std::vector<Keyframes> fingers);
    bool fingers_posed() const { return !posed_fingers_.empty(); }
    // A skeleton hand's session: its bones (1 for the palm handle's), and the groups its feedback
    // is summed in (FeedbackGroups; set while stopped).
    int n_bones() const;
    std::vector<Pose> bone_poses() const;  // every bone's pose now (a stopped session)
    void set_feedback_groups(const FeedbackGroups& groups);
    int n_groups() const;
    // the host-pushed one-frame device, also when it is the wrist of a wrist glove
    ExternalDevice* external_device() { return external_; }
    ExternalFrames* external_frames() { return external_frames_; }
    // The handle's pose now (a stopped session): where a device that has not spoken yet holds it.
    Pose handle_pose() const;

    // Offline: visual_steps visual steps, each preceded by its haptic steps, in the caller's
    // thread. Throws InvalidArgument when the device disconnects (the state so far is kept).
    void run_offline(int visual_steps);
    // Live: starts the threads (returns at once); stop() joins them. Never throws from the
    // threads: a failure ends the session and is reported by error().
    void start();
    void stop() noexcept;
    bool running() const { return running_.load(std::memory_order_acquire); }
    // whether the haptic thread got real-time priority
    bool realtime() const { return realtime_.load(std::memory_order_acquire); }
    // the last live haptic thread's setup and the page faults (minor, major) in its loop; valid
    // once stop() has returned
    const LoopSetup& loop_setup() const { return loop_; }
    double loop_minor_faults() const { return loop_minor_faults_; }
    double loop_major_faults() const { return loop_major_faults_; }
    bool failed() const { return failed_.load(std::memory_order_acquire); }
    const char* error() const { return failed() ? message_ : ""; }

    // Host side (one consumer thread): newest frame, true when it changed since the last call.
    bool fetch_frame() { return frames_.fetch(); }
    const Frame& frame() const { return frames_.front(); }
    const std::vector<int>& surface_offsets() const { return surface_offset_; }  // in vertices, per body
    HapticLog& log() { return log_; }
    std::uint64_t haptic_steps() const { return haptic_steps_.load(std::memory_order_acquire); }
    std::uint64_t visual_steps() const { return visual_steps_.load(std::memory_order_acquire); }
    const SessionParams& params() const { return p_; }
    const ProxyHandle& proxy() const { return proxy_; }  // offline only (live: the haptic thread owns it)

    // one haptic step ending at time t
    bool haptic_step(double t) noexcept;
    // the device driver's servo loop calls this (through a trampoline) at its own rate
    void servo_step() noexcept;

private:
    // A skeleton hand's loops (haptics/session_bones.cpp): the visual step drives every bone to
    // its proxy and publishes the bones' model; the haptic step moves the B proxies
    struct Bones;
    std::unique_ptr<Bones> bones_;
    bool bones_haptic_step(double t, double start) noexcept;
    // the feedback clamped to the session's and the device's limits (clamp false: only checked;
    // false, the session failed: not finite), and the step's log row (the root's device frame,
    // proxy and feedback)
    bool limit_feedback(Feedback& fb, bool clamp = true) noexcept;
    void log_step(double t, double start, const Pose& dev, const HandleState& proxy, const Feedback& fb) noexcept;
    void bones_visual_step();
    void bones_publish_frame(Frame& f);
    void visual_step();
    void publish_frame();
    void fail(const char* message) noexcept;
    void haptic_thread() noexcept;
    void visual_thread() noexcept;

    World& world_;
    int hand_;
    SessionParams p_;
    // the haptic clock: step n of the current rate at clock_origin_ + n / rate_ (s)
    double rate_ = 1000;  // Hz: the session's, or the device's servo loop's
    double dt_haptic_ = 1e-3;
    double clock_origin_ = 0;
    std::uint64_t clock_steps_ = 0;
    void set_clock_rate(double rate);  // restarts the count from the present time t_haptic_
    double advance_clock();            // the next step's time
    std::unique_ptr<Device> device_;
    ExternalDevice* external_ = nullptr;
    ExternalFrames* external_frames_ = nullptr;
    WristGlove* wrist_ = nullptr;             // the device when it is a one-frame device with the fingers posed
    std::vector<Keyframes> posed_fingers_;    // pose_fingers'
    std::unique_ptr<Device> wrap_wrist(std::unique_ptr<Device> device);

    // haptic side
    ProxyHandle proxy_;
    double t_haptic_ = 0;        // s: the haptic clock's present (virtual offline, nominal live)
    double last_tick_wall_ = -1;
    bool live_ = false;
    TripleBuffer<CouplingModel> models_;   // visual -> haptic
    TripleBuffer<ProxySample> samples_;    // haptic -> visual
    TripleBuffer<Frame> frames_;           // visual -> host
    HapticLog log_;

    // visual side
    ProxySample sample_;  // the latest proxy sample it saw
    bool have_previous_step_ = false;
    Vec3 previous_v_ = Vec3::Zero(), previous_omega_ = Vec3::Zero();  // the last step's handle velocity
    std::vector<int> surface_offset_;

    // the live haptic thread's own setup and the page faults it took in the loop (its thread
    // writes them; read them after stop())
    LoopSetup loop_;
    double loop_minor_faults_ = 0, loop_major_faults_ = 0;
    std::atomic<bool> running_{false}, stop_{false}, failed_{false}, failing_{false}, realtime_{false};
    std::atomic<std::uint64_t> haptic_steps_{0}, visual_steps_{0};
    char message_[512] = {0};
    std::thread haptic_thread_, visual_thread_;
    double wall_start_ = 0;
};

}  // namespace hh
