// The C ABI from C++: RAII handles, one immutable lens shared by several threads, and the
// numbers tests/capi.rs compares with the Rust API. Prints "RESULT <key> <value>" lines.
#include "tolray.h"

#include <cstdio>
#include <memory>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace {

struct LensFree {
    void operator()(tolray_lens *p) const { tolray_lens_free(p); }
};
struct SystemFree {
    void operator()(tolray_system *p) const { tolray_system_free(p); }
};
using Lens = std::unique_ptr<tolray_lens, LensFree>;
using System = std::unique_ptr<tolray_system, SystemFree>;

void check(tolray_status s, const char *what) {
    if (s != TOLRAY_OK) {
        std::string msg(tolray_last_error(nullptr, 0) + 1, '\0');
        tolray_last_error(&msg[0], msg.size());
        throw std::runtime_error(std::string(what) + ": " + tolray_status_str(s) + ": " + msg);
    }
}

Lens load(const char *name) {
    tolray_lens *p = nullptr;
    check(tolray_lens_load(name, &p), "tolray_lens_load");
    return Lens(p);
}

System compile(const tolray_lens *lens) {
    tolray_system *p = nullptr;
    check(tolray_system_new(lens, nullptr, &p), "tolray_system_new");
    return System(p);
}

}  // namespace

int main() {
    try {
        Lens lens = load("cooke-triplet");
        System sys = compile(lens.get());
        const tolray_pupil grid{TOLRAY_PUPIL_GRID, 32, 0, 1.0, 0};
        const double d_line = 587.5618;

        // Several threads read the same immutable handles at once.
        std::vector<double> rms(4);
        std::vector<std::thread> threads;
        for (int t = 0; t < 4; t++) {
            threads.emplace_back([&, t] {
                const tolray_field f{TOLRAY_FIELD_FRACTION, 0.0, t < 2 ? 0.0 : 0.7};
                tolray_spot_stats st{};
                if (tolray_spot(sys.get(), &f, &d_line, 1, &grid, 1, &st) == TOLRAY_OK)
                    rms[t] = st.rms_um;
            });
        }
        for (auto &th : threads) th.join();
        if (rms[0] != rms[1] || rms[2] != rms[3] || rms[0] <= 0.0)
            throw std::runtime_error("threads disagree");
        std::printf("RESULT spot_rms_um_field0 %.17g\n", rms[0]);
        std::printf("RESULT spot_rms_um_field1 %.17g\n", rms[2]);

        const tolray_field fields[2] = {{TOLRAY_FIELD_FRACTION, 0.0, 0.0},
                                        {TOLRAY_FIELD_FRACTION, 0.0, 0.7}};
        const tolray_param vars[3] = {{TOLRAY_PARAM_CURVATURE, 0, 0},
                                      {TOLRAY_PARAM_CURVATURE, 3, 0},
                                      {TOLRAY_PARAM_GAP, 2, 0}};
        const tolray_pupil g8{TOLRAY_PUPIL_GRID, 8, 0, 1.0, 0};
        double loss = 0.0, grad[3] = {};
        check(tolray_spot_loss_gradient(sys.get(), fields, 2, &d_line, 1, &g8, TOLRAY_SPOT_MEAN,
                                        vars, 3, &loss, grad),
              "tolray_spot_loss_gradient");
        std::printf("RESULT nominal_spot_loss %.17g\n", loss);
        std::printf("RESULT nominal_spot_grad %.17g %.17g %.17g\n", grad[0], grad[1], grad[2]);

        // An error comes back as a status and a message, not an exception or a crash.
        tolray_lens *bad = nullptr;
        tolray_status s = tolray_lens_from_json("not json", &bad);
        if (s != TOLRAY_ERROR_PARSE || bad != nullptr) throw std::runtime_error("bad JSON accepted");
        std::printf("C++ ABI test passed\n");
        return 0;
    } catch (const std::exception &e) {
        std::fprintf(stderr, "FAILED: %s\n", e.what());
        return 1;
    }
}
