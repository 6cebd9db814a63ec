// Phantom Omni / Touch through the OpenHaptics HD API, loaded at run time with dlopen so the
// library builds and runs without the vendor's SDK. The driver's own servo loop (started by
// hdStartScheduler, about 1 kHz) calls the session's haptic step through an asynchronous
// scheduler callback; inside it the backend reads HD_CURRENT_TRANSFORM (mm, column-major 4x4)
// and writes HD_CURRENT_FORCE (N). Device axes (x right, y up, z toward the user, mm) map to
// the scene's (x, -z, y) in metres, scaled by `workspace_scale` about `workspace_origin`.
#pragma once
#include <string>

#include "device/device.h"

namespace hh {

struct OpenHapticsParams {
    std::string library = "libHD.so";  // a path, or a name the dynamic loader searches
    double workspace_scale = 1.0;      // scene metres per device metre
    Vec3 workspace_origin = Vec3::Zero();  // scene point of the device's origin
    double max_force = 3.3;            // N: the Phantom Omni / Touch's peak force (3D Systems' spec sheet)
};

class OpenHapticsDevice : public Device {
public:
    // Loads the library and resolves the HD functions; throws InvalidArgument with a message
    // saying what is missing and how to install it.
    explicit OpenHapticsDevice(const OpenHapticsParams& params);
    ~OpenHapticsDevice() override;
    const char* name() const override { return "openhaptics"; }
    bool read(double t, Pose& out) noexcept override;
    void command(const Feedback& fb) noexcept override;
    bool has_servo_loop() const override { return true; }
    void start_servo(void (*tick)(void*), void* user) override;
    void stop_servo() noexcept override;

    struct Api;  // the resolved HD entry points

private:
    static unsigned int servo_callback(void* self);
    OpenHapticsParams p_;
    void* library_ = nullptr;
    Api* api_ = nullptr;
    unsigned int device_ = 0;
    unsigned long scheduled_ = 0;
    bool scheduler_running_ = false;
    void (*tick_)(void*) = nullptr;
    void* tick_user_ = nullptr;
    double t_ = 0;
    bool have_last_ = false;
    Pose last_;
};

}  // namespace hh
