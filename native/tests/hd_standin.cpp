// A stand-in for the OpenHaptics HD library, built by the tests: it exports the HD functions
// the openhaptics backend loads, runs the scheduled callback on its own 1 kHz thread like the
// vendor's servo loop, reports a position the test sets (in millimetres, device axes) and
// records the force it is told to display. Test hooks start with standin_.
#include <atomic>
#include <chrono>
#include <thread>

namespace {
std::atomic<double> position_mm[3] = {{0.0}, {0.0}, {0.0}};
std::atomic<double> force[3] = {{0.0}, {0.0}, {0.0}};
std::atomic<long> ticks{0};
std::atomic<bool> failing{false}, running{false};
std::atomic<unsigned int (*)(void*)> callback{nullptr};
std::atomic<void*> callback_data{nullptr};
std::thread servo;

struct ErrorInfo {
    unsigned int code;
    int internal_code;
    unsigned int device;
};
}  // namespace

extern "C" {
__attribute__((visibility("default"))) unsigned int hdInitDevice(const char*) { return 7; }
__attribute__((visibility("default"))) void hdMakeCurrentDevice(unsigned int) {}
__attribute__((visibility("default"))) void hdEnable(unsigned int) {}
__attribute__((visibility("default"))) void hdDisableDevice(unsigned int) {}
__attribute__((visibility("default"))) void hdBeginFrame(unsigned int) {}
__attribute__((visibility("default"))) void hdEndFrame(unsigned int) {}

__attribute__((visibility("default"))) unsigned long hdScheduleAsynchronous(unsigned int (*cb)(void*), void* data,
                                                                             unsigned short) {
    callback_data.store(data);
    callback.store(cb);
    return 1;
}
__attribute__((visibility("default"))) void hdUnschedule(unsigned long) { callback.store(nullptr); }

__attribute__((visibility("default"))) void hdStartScheduler() {
    running.store(true);
    servo = std::thread([] {
        auto next = std::chrono::steady_clock::now();
        while (running.load()) {
            next += std::chrono::microseconds(1000);
            std::this_thread::sleep_until(next);
            auto* cb = callback.load();
            if (!cb) continue;
            ++ticks;
            if (cb(callback_data.load()) == 0) callback.store(nullptr);  // HD_CALLBACK_DONE
        }
    });
}
__attribute__((visibility("default"))) void hdStopScheduler() {
    running.store(false);
    if (servo.joinable()) servo.join();
}

__attribute__((visibility("default"))) void hdGetDoublev(unsigned int name, double* out) {
    if (name == 0x2052) {  // HD_CURRENT_TRANSFORM: column-major 4x4, identity rotation
        for (int i = 0; i < 16; ++i) out[i] = (i % 5 == 0) ? 1.0 : 0.0;
        for (int i = 0; i < 3; ++i) out[12 + i] = position_mm[i].load();
    }
}
__attribute__((visibility("default"))) void hdSetDoublev(unsigned int name, const double* in) {
    if (name == 0x2700)  // HD_CURRENT_FORCE
        for (int i = 0; i < 3; ++i) force[i].store(in[i]);
}
__attribute__((visibility("default"))) ErrorInfo hdGetError() {
    return ErrorInfo{failing.load() ? 0x300u : 0u, 0, 7};
}

// --- test hooks ---
__attribute__((visibility("default"))) void standin_set_position(const double mm[3]) {
    for (int i = 0; i < 3; ++i) position_mm[i].store(mm[i]);
}
__attribute__((visibility("default"))) void standin_get_force(double out[3]) {
    for (int i = 0; i < 3; ++i) out[i] = force[i].load();
}
__attribute__((visibility("default"))) long standin_ticks() { return ticks.load(); }
__attribute__((visibility("default"))) void standin_set_failing(int on) { failing.store(on != 0); }
}
