/* The C ABI from C: numbers for tests/capi.rs to compare with the Rust API, then every error
 * path. Prints "RESULT <key> <value>" lines; exits non-zero on the first unexpected outcome. */
#include "tolray.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int failures = 0;

#define CHECK(cond)                                                                    \
    do {                                                                               \
        if (!(cond)) {                                                                 \
            char msg_[512];                                                            \
            tolray_last_error(msg_, sizeof msg_);                                      \
            fprintf(stderr, "FAILED %s:%d: %s (last error: %s)\n", __FILE__, __LINE__, \
                    #cond, msg_);                                                      \
            failures++;                                                                \
        }                                                                              \
    } while (0)

/* Expects `call` to return `want` and leave a message that contains `needle`. */
static void expect_error(const char *what, tolray_status got, tolray_status want,
                         const char *needle) {
    char msg[512];
    size_t len = tolray_last_error(msg, sizeof msg);
    if (got != want || len == 0 || strstr(msg, needle) == NULL) {
        fprintf(stderr, "FAILED error path %s: status %u (%s), want %u; message \"%s\"\n", what,
                (unsigned)got, tolray_status_str(got), (unsigned)want, msg);
        failures++;
    } else {
        printf("ERROR %s: %s: %s\n", what, tolray_status_str(got), msg);
    }
}

int main(void) {
    /* Versions: the header's macros against the library. */
    CHECK(strcmp(tolray_version(), TOLRAY_VERSION_STRING) == 0);
    CHECK(tolray_abi_version() == TOLRAY_ABI_VERSION);
    char version[32];
    snprintf(version, sizeof version, "%d.%d.%d", TOLRAY_VERSION_MAJOR, TOLRAY_VERSION_MINOR,
             TOLRAY_VERSION_PATCH);
    CHECK(strcmp(version, tolray_version()) == 0);
    printf("RESULT version %s\n", tolray_version());

    /* The cooke triplet: paraxial data and the on-axis and 0.7-field spots. */
    tolray_lens *lens = NULL;
    CHECK(tolray_lens_load("cooke-triplet", &lens) == TOLRAY_OK);
    if (lens == NULL) return 1;
    tolray_paraxial para;
    CHECK(tolray_lens_paraxial(lens, 587.5618, &para) == TOLRAY_OK);
    printf("RESULT efl_mm %.17g\n", para.efl_mm);
    printf("RESULT num_surfaces %u\n", para.num_surfaces);

    tolray_system *nominal = NULL;
    CHECK(tolray_system_new(lens, NULL, &nominal) == TOLRAY_OK);
    const double wl[3] = {486.1327, 587.5618, 656.2725};
    tolray_pupil grid = {TOLRAY_PUPIL_GRID, 32, 0, 1.0, 0};
    tolray_field fields[2] = {{TOLRAY_FIELD_FRACTION, 0.0, 0.0}, {TOLRAY_FIELD_FRACTION, 0.0, 0.7}};
    for (int f = 0; f < 2; f++) {
        tolray_spot_stats st;
        CHECK(tolray_spot(nominal, &fields[f], &wl[1], 1, &grid, 1, &st) == TOLRAY_OK);
        printf("RESULT spot_rms_um_field%d %.17g\n", f, st.rms_um);
        printf("RESULT spot_valid_field%d %llu\n", f, (unsigned long long)st.n_valid);
    }
    tolray_spot_stats poly;
    CHECK(tolray_spot(nominal, &fields[1], wl, 3, &grid, 1, &poly) == TOLRAY_OK);
    printf("RESULT spot_rms_um_poly %.17g\n", poly.rms_um);

    /* A sampled tolerance pattern, applied, and a fan of rays traced through it. */
    tolray_spec *spec = NULL;
    tolray_pattern *pattern = NULL;
    tolray_system *perturbed = NULL;
    CHECK(tolray_spec_default(&spec) == TOLRAY_OK);
    CHECK(tolray_pattern_sample(spec, lens, 7, 3, &pattern) == TOLRAY_OK);
    CHECK(tolray_system_new(lens, pattern, &perturbed) == TOLRAY_OK);
    size_t json_len = 0;
    CHECK(tolray_pattern_to_json(pattern, NULL, 0, &json_len) == TOLRAY_OK && json_len > 0);

    enum { N = 9 };
    double x[N], y[N], z[N], dx[N], dy[N], dz[N];
    double ox[N], oy[N], oz[N], odx[N], ody[N], odz[N], opl[N];
    uint32_t status[N];
    for (int i = 0; i < N; i++) {
        x[i] = 0.3;
        y[i] = -16.0 + 4.0 * i;
        z[i] = -5.0;
        dx[i] = 0.0;
        dy[i] = 0.02;
        dz[i] = 1.0;
    }
    tolray_rays_in in = {x, y, z, dx, dy, dz};
    tolray_rays_out out = {ox, oy, oz, odx, ody, odz, opl, status};
    CHECK(tolray_trace(perturbed, 587.5618, TOLRAY_TRACE_APERTURES, N, &in, &out) == TOLRAY_OK);
    for (int i = 0; i < N; i++)
        printf("RESULT trace%d %.17g %.17g %.17g %.17g %.17g %.17g %.17g %u\n", i, ox[i], oy[i],
               oz[i], odx[i], ody[i], odz[i], opl[i], status[i]);
    /* In place: the outputs may be the input arrays. */
    tolray_rays_out inplace = {x, y, z, dx, dy, dz, NULL, status};
    CHECK(tolray_trace(perturbed, 587.5618, TOLRAY_TRACE_APERTURES, N, &in, &inplace) ==
          TOLRAY_OK);
    for (int i = 0; i < N; i++) CHECK(x[i] == ox[i] && y[i] == oy[i] && dz[i] == odz[i]);

    /* Gradient of the spot loss of the perturbed lens w.r.t. three design variables. */
    tolray_param vars[3] = {{TOLRAY_PARAM_CURVATURE, 0, 0},
                            {TOLRAY_PARAM_CURVATURE, 3, 0},
                            {TOLRAY_PARAM_GAP, 2, 0}};
    double loss = 0, grad[3] = {0, 0, 0};
    tolray_pupil g8 = {TOLRAY_PUPIL_GRID, 8, 0, 1.0, 0};
    CHECK(tolray_spot_loss_gradient(perturbed, fields, 2, &wl[1], 1, &g8, TOLRAY_SPOT_MEAN, vars,
                                    3, &loss, grad) == TOLRAY_OK);
    printf("RESULT spot_loss %.17g\n", loss);
    printf("RESULT spot_grad %.17g %.17g %.17g\n", grad[0], grad[1], grad[2]);

    /* A PSF: sums to 1. */
    tolray_psf_options popts;
    CHECK(tolray_psf_options_default(nominal, &popts) == TOLRAY_OK);
    popts.kernel_px = 15;
    popts.pupil.n = 2048;
    double psf[15 * 15];
    CHECK(tolray_psf(perturbed, &fields[1], 587.5618, &popts, psf, 15 * 15) == TOLRAY_OK);
    double sum = 0, peak = 0;
    for (int i = 0; i < 15 * 15; i++) {
        sum += psf[i];
        if (psf[i] > peak) peak = psf[i];
    }
    printf("RESULT psf_sum %.17g\n", sum);
    printf("RESULT psf_peak %.17g\n", peak);
    double psf_loss = 0, psf_grad[1] = {0};
    CHECK(tolray_psf_loss_gradient(perturbed, &fields[1], 1, &wl[1], 1, &popts, vars, 1, &psf_loss,
                                   psf_grad) == TOLRAY_OK);
    printf("RESULT psf_loss %.17g %.17g\n", psf_loss, psf_grad[0]);

    /* A lens stepped by one variable, and the JSON round trip. */
    tolray_lens *stepped = NULL;
    double c0 = 0;
    CHECK(tolray_lens_param_get(lens, &vars[0], &c0) == TOLRAY_OK);
    CHECK(tolray_lens_with_param(lens, &vars[0], c0 * 0.99, &stepped) == TOLRAY_OK);
    double c1 = 0;
    CHECK(tolray_lens_param_get(stepped, &vars[0], &c1) == TOLRAY_OK && c1 == c0 * 0.99);
    size_t n = 0;
    CHECK(tolray_lens_to_json(lens, NULL, 0, &n) == TOLRAY_OK);
    char *json = malloc(n + 1);
    CHECK(tolray_lens_to_json(lens, json, n + 1, &n) == TOLRAY_OK && strlen(json) == n);
    tolray_lens *again = NULL;
    CHECK(tolray_lens_from_json(json, &again) == TOLRAY_OK);
    tolray_paraxial para2;
    CHECK(tolray_lens_paraxial(again, 587.5618, &para2) == TOLRAY_OK &&
          para2.efl_mm == para.efl_mm);

    /* Error paths: each gives its status and a message; outputs stay untouched. */
    tolray_lens *none = (tolray_lens *)0x1; /* must not be overwritten on failure */
    expect_error("NULL name", tolray_lens_load(NULL, &none), TOLRAY_ERROR_NULL_ARGUMENT,
                 "name_or_path is NULL");
    CHECK(none == (tolray_lens *)0x1);
    expect_error("unknown built-in", tolray_lens_load("no-such-lens", &none), TOLRAY_ERROR_IO,
                 "not a built-in lens");
    expect_error("malformed JSON", tolray_lens_from_json("{\"surfaces\": [", &none),
                 TOLRAY_ERROR_PARSE, "line 1");
    expect_error("invalid lens", tolray_lens_from_json("{\"surfaces\": []}", &none),
                 TOLRAY_ERROR_INVALID_INPUT, "");
    CHECK(none == (tolray_lens *)0x1);
    expect_error("NULL out", tolray_lens_load("lens1", NULL), TOLRAY_ERROR_NULL_ARGUMENT, "out");
    expect_error("NULL lens", tolray_lens_paraxial(NULL, 587.6, &para), TOLRAY_ERROR_NULL_ARGUMENT,
                 "lens is NULL");
    expect_error("NULL system", tolray_spot(NULL, &fields[0], wl, 1, &grid, 1, &poly),
                 TOLRAY_ERROR_NULL_ARGUMENT, "system is NULL");
    expect_error("NULL output array", tolray_trace(perturbed, 587.6, 0, N, &in,
                 &(tolray_rays_out){ox, oy, oz, odx, ody, NULL, NULL, status}),
                 TOLRAY_ERROR_NULL_ARGUMENT, "out->dz");
    expect_error("bad wavelength", tolray_lens_paraxial(lens, 0.5876, &para), TOLRAY_ERROR_ARGUMENT,
                 "nanometres");
    expect_error("zero wavelengths", tolray_spot(nominal, &fields[0], wl, 0, &grid, 1, &poly),
                 TOLRAY_ERROR_BUFFER_SIZE, "n_wavelengths");
    double small[4];
    expect_error("PSF buffer size", tolray_psf(nominal, &fields[0], 587.6, &popts, small, 4),
                 TOLRAY_ERROR_BUFFER_SIZE, "needs 225");
    char tiny[8] = "xxxxxxx";
    size_t len_out = 12345;
    expect_error("JSON buffer size", tolray_lens_to_json(lens, tiny, sizeof tiny, &len_out),
                 TOLRAY_ERROR_BUFFER_SIZE, "holds 8 bytes");
    CHECK(len_out == 12345 && strcmp(tiny, "xxxxxxx") == 0);
    tolray_field bad_field = {99, 0.0, 0.0};
    expect_error("unknown field kind", tolray_spot(nominal, &bad_field, wl, 1, &grid, 1, &poly),
                 TOLRAY_ERROR_ARGUMENT, "field kind 99");
    tolray_param bad_param = {TOLRAY_PARAM_CURVATURE, 40, 0};
    expect_error("surface out of range",
                 tolray_spot_loss_gradient(nominal, fields, 1, wl, 1, &g8, TOLRAY_SPOT_MEAN,
                                           &bad_param, 1, &loss, grad),
                 TOLRAY_ERROR_ARGUMENT, "surface 40");
    tolray_param glass = {TOLRAY_PARAM_GLASS_ND, 1, 0}; /* air follows surface 1 */
    expect_error("not a model glass", tolray_lens_param_get(lens, &glass, &c0),
                 TOLRAY_ERROR_ARGUMENT, "model glass");
    expect_error("bad pattern JSON", tolray_pattern_from_json("{\"elements\": 3}", &pattern),
                 TOLRAY_ERROR_PARSE, "line 1");
    tolray_pattern *far = NULL;
    CHECK(tolray_pattern_from_json("{\"elements\": [{\"element\": 9, \"decenter_mm\": [0.1, 0]}]}",
                                   &far) == TOLRAY_OK);
    tolray_system *none_sys = NULL;
    expect_error("pattern out of range", tolray_system_new(lens, far, &none_sys),
                 TOLRAY_ERROR_INVALID_INPUT, "element 9");
    CHECK(none_sys == NULL);
    expect_error("missing spec file", tolray_spec_load("/no/such/spec.json", &spec),
                 TOLRAY_ERROR_IO, "/no/such/spec.json");
    CHECK(strcmp(tolray_status_str(12345), "unknown status") == 0);
    /* Truncation of the last error: NUL-terminated, full length returned. */
    char four[4];
    size_t full = tolray_last_error(four, sizeof four);
    CHECK(full > 3 && strlen(four) == 3);
    CHECK(tolray_last_error(NULL, 0) == full);

    tolray_lens_free(NULL);
    tolray_spec_free(NULL);
    tolray_pattern_free(NULL);
    tolray_system_free(NULL);
    tolray_pattern_free(far);
    tolray_lens_free(again);
    tolray_lens_free(stepped);
    free(json);
    tolray_system_free(perturbed);
    tolray_pattern_free(pattern);
    tolray_spec_free(spec);
    tolray_system_free(nominal);
    tolray_lens_free(lens);
    if (failures) {
        fprintf(stderr, "%d failures\n", failures);
        return 1;
    }
    printf("C ABI test passed\n");
    return 0;
}
