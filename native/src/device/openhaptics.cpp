#include "device/openhaptics.h"

#include <dlfcn.h>

#include <atomic>

#include "rigid/quaternion.h"

namespace hh {

namespace {
// HD API values (OpenHaptics HD API reference): parameter names for hdGet/hdSet, the
// capability that turns on force output, callback return codes, the invalid handle.
constexpr unsigned int kCurrentTransform = 0x2052;
constexpr unsigned int kCurrentForce = 0x2700;
constexpr unsigned int kForceOutput = 0x4000;
constexpr unsigned int kCallbackDone = 0;
constexpr unsigned int kCallbackContinue = 1;
constexpr unsigned int kInvalidHandle = 0xFFFFFFFFu;
constexpr unsigned short kMaxSchedulerPriority = 0xFFFF;
constexpr double kServoPeriod = 1e-3;  // s: the HD scheduler's nominal rate is 1 kHz

struct ErrorInfo {
    unsigned int code;
    int internal_code;
    unsigned int device;
};

// Scene axes from device axes: x right, y up, z toward the user -> x, -z, y (z up).
Mat3 device_to_scene() {
    Mat3 m;
    m << 1, 0, 0, 0, 0, -1, 0, 1, 0;
    return m;
}
}  // namespace

struct OpenHapticsDevice::Api {
    unsigned int (*init_device)(const char*);
    void (*make_current)(unsigned int);
    void (*enable)(unsigned int);
    void (*start_scheduler)();
    void (*stop_scheduler)();
    unsigned long (*schedule_async)(unsigned int (*)(void*), void*, unsigned short);
    void (*unschedule)(unsigned long);
    void (*begin_frame)(unsigned int);
    void (*end_frame)(unsigned int);
    void (*get_doublev)(unsigned int, double*);
    void (*set_doublev)(unsigned int, const double*);
    ErrorInfo (*get_error)();
    void (*disable_device)(unsigned int);
};

OpenHapticsDevice::OpenHapticsDevice(const OpenHapticsParams& params) : p_(params) {
    max_force = params.max_force;
    library_ = dlopen(p_.library.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (!library_) {
        const char* why = dlerror();
        throw InvalidArgument("OpenHaptics is not installed: could not load '" + p_.library + "' (" +
                              (why ? why : "unknown reason") +
                              "). Install the OpenHaptics runtime and the Touch device driver from 3D Systems, "
                              "or give the library's full path; without it choose the 'simulated' device.");
    }
    auto* api = new Api{};
    auto need = [&](const char* symbol, auto& fn) {
        void* f = dlsym(library_, symbol);
        if (!f) {
            delete api;
            dlclose(library_);
            library_ = nullptr;
            throw InvalidArgument("'" + p_.library + "' is not an OpenHaptics HD library: it lacks " + symbol +
                                  ". Point the device at libHD.so from the OpenHaptics runtime.");
        }
        fn = reinterpret_cast<std::remove_reference_t<decltype(fn)>>(f);
    };
    need("hdInitDevice", api->init_device);
    need("hdMakeCurrentDevice", api->make_current);
    need("hdEnable", api->enable);
    need("hdStartScheduler", api->start_scheduler);
    need("hdStopScheduler", api->stop_scheduler);
    need("hdScheduleAsynchronous", api->schedule_async);
    need("hdUnschedule", api->unschedule);
    need("hdBeginFrame", api->begin_frame);
    need("hdEndFrame", api->end_frame);
    need("hdGetDoublev", api->get_doublev);
    need("hdSetDoublev", api->set_doublev);
    need("hdGetError", api->get_error);
    need("hdDisableDevice", api->disable_device);
    api_ = api;
}

OpenHapticsDevice::~OpenHapticsDevice() {
    stop_servo();
    delete api_;
    if (library_) dlclose(library_);
}

void OpenHapticsDevice::start_servo(void (*tick)(void*), void* user) {
    tick_ = tick;
    tick_user_ = user;
    device_ = api_->init_device(nullptr);  // the default device
    const ErrorInfo err = api_->get_error();
    if (device_ == kInvalidHandle || err.code != 0)
        throw InvalidArgument("no OpenHaptics device answered (HD error " + std::to_string(err.code) +
                              "): check that the Touch is plugged in, configured with Touch Setup, and not in "
                              "use by another program");
    api_->make_current(device_);
    api_->enable(kForceOutput);
    scheduled_ = api_->schedule_async(&OpenHapticsDevice::servo_callback, this, kMaxSchedulerPriority);
    api_->start_scheduler();
    scheduler_running_ = true;
}

void OpenHapticsDevice::stop_servo() noexcept {
    if (!scheduler_running_) return;
    scheduler_running_ = false;
    api_->stop_scheduler();
    api_->unschedule(scheduled_);
    api_->disable_device(device_);
}

unsigned int OpenHapticsDevice::servo_callback(void* self_ptr) {
    auto* self = static_cast<OpenHapticsDevice*>(self_ptr);
    self->api_->begin_frame(self->device_);
    self->tick_(self->tick_user_);  // the session's haptic step: read() then command()
    self->api_->end_frame(self->device_);
    return self->error_[0] ? kCallbackDone : kCallbackContinue;
}

bool OpenHapticsDevice::read(double t, Pose& out) noexcept {
    double m[16];
    api_->get_doublev(kCurrentTransform, m);
    const ErrorInfo err = api_->get_error();
    if (err.code != 0) {
        fail("the OpenHaptics device stopped answering (disconnected or overheated)", t);
        return false;
    }
    const Mat3 axes = device_to_scene();
    Mat3 rot;  // column-major: m[4 c + r]
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) rot(r, c) = m[4 * c + r];
    const Vec3 p_mm(m[12], m[13], m[14]);
    Pose pose;
    pose.position = p_.workspace_origin + p_.workspace_scale * 1e-3 * (axes * p_mm);
    pose.quaternion = quat_from_matrix(axes * rot * axes.transpose());
    if (have_last_ && t > t_) {
        pose.velocity = (pose.position - last_.position) / (t - t_);
        pose.angular_velocity =
            quat_to_rotation_vector(quat_multiply(pose.quaternion, quat_conjugate(last_.quaternion))) / (t - t_);
    }
    last_ = pose;
    have_last_ = true;
    t_ = t;
    out = pose;
    return true;
}

void OpenHapticsDevice::command(const Feedback& fb) noexcept {
    // forces act in device axes and are not scaled with the workspace (N are N)
    const Vec3 f = device_to_scene().transpose() * fb.force;
    const double v[3] = {f.x(), f.y(), f.z()};
    api_->set_doublev(kCurrentForce, v);
}

}  // namespace hh
