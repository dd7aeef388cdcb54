// The on-axis spot and its gradient with respect to the first curvature, from C++.
// Build: cmake -B build -DCMAKE_PREFIX_PATH=PREFIX && cmake --build build; run: build/spot
#include <tolray.h>

#include <cstdio>
#include <memory>

int main() {
    tolray_lens *raw = nullptr;
    if (tolray_lens_load("cooke-triplet", &raw) != TOLRAY_OK) return 1;
    std::unique_ptr<tolray_lens, void (*)(tolray_lens *)> lens(raw, tolray_lens_free);
    tolray_system *sys_raw = nullptr;
    if (tolray_system_new(lens.get(), nullptr, &sys_raw) != TOLRAY_OK) return 1;
    std::unique_ptr<tolray_system, void (*)(tolray_system *)> sys(sys_raw, tolray_system_free);

    const double wl = 587.5618;
    const tolray_field axis{TOLRAY_FIELD_FRACTION, 0.0, 0.0};
    const tolray_pupil pupil{TOLRAY_PUPIL_GRID, 16, 0, 1.0, 0};
    const tolray_param c0{TOLRAY_PARAM_CURVATURE, 0, 0};
    double loss = 0, dloss_dc0 = 0;
    if (tolray_spot_loss_gradient(sys.get(), &axis, 1, &wl, 1, &pupil, TOLRAY_SPOT_RMS, &c0, 1,
                                  &loss, &dloss_dc0) != TOLRAY_OK) {
        char msg[256];
        tolray_last_error(msg, sizeof msg);
        std::fprintf(stderr, "%s\n", msg);
        return 1;
    }
    std::printf("RMS spot %.3f um, d(RMS)/d(c0) = %.3f mm^2\n", loss * 1e3, dloss_dc0);
    return 0;
}
