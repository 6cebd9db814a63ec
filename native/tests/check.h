// A minimal test harness for the native tests: TEST(name) registers a function, CHECK
// records a failure with file and line, main() runs all and prints "N passed, N failed".
#pragma once
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <string>
#include <vector>

namespace check {
struct Case {
    const char* name;
    std::function<void()> body;
};
inline std::vector<Case>& cases() {
    static std::vector<Case> all;
    return all;
}
inline int& failures() {
    static int n = 0;
    return n;
}
struct Register {
    Register(const char* name, std::function<void()> body) { cases().push_back({name, std::move(body)}); }
};
inline std::string num(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.3g", v);
    return buf;
}
inline void fail(const char* file, int line, const std::string& what) {
    std::fprintf(stderr, "%s:%d: CHECK failed: %s\n", file, line, what.c_str());
    ++failures();
}
}  // namespace check

#define TEST(name)                                                   \
    static void name();                                              \
    static check::Register register_##name(#name, name);             \
    static void name()

#define CHECK(cond)                                                  \
    do {                                                             \
        if (!(cond)) check::fail(__FILE__, __LINE__, #cond);         \
    } while (0)

#define CHECK_LT(a, b)                                                                        \
    do {                                                                                      \
        const double va_ = (a), vb_ = (b);                                                    \
        if (!(va_ < vb_))                                                                     \
            check::fail(__FILE__, __LINE__, std::string(#a " < " #b ": ") + check::num(va_) + \
                                                " vs " + check::num(vb_));                    \
    } while (0)

int main() {
    int passed = 0, failed = 0;
    // CHECK_ONLY=text: only the cases whose name holds it (make test-tsan runs one case of a
    // suite that is slow under ThreadSanitizer)
    const char* only = std::getenv("CHECK_ONLY");
    for (const auto& c : check::cases()) {
        if (only && !std::strstr(c.name, only)) continue;
        const int before = check::failures();
        c.body();
        if (check::failures() == before) {
            ++passed;
        } else {
            ++failed;
            std::fprintf(stderr, "FAILED: %s\n", c.name);
        }
    }
    std::printf("%d passed, %d failed\n", passed, failed);
    return failed == 0 ? 0 : 1;
}
