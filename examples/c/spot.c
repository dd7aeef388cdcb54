/* Spot sizes of a built-in lens, nominal and with one sampled tolerance pattern.
 * Build: make (uses pkg-config, see ../../README.md "C ABI"); run: ./spot [lens]. */
#include <stdio.h>
#include <tolray.h>

static int fail(tolray_status s) {
    char msg[512];
    tolray_last_error(msg, sizeof msg);
    fprintf(stderr, "tolray: %s: %s\n", tolray_status_str(s), msg);
    return 1;
}

int main(int argc, char **argv) {
    const char *name = argc > 1 ? argv[1] : "cooke-triplet";
    tolray_lens *lens = NULL;
    tolray_spec *spec = NULL;
    tolray_pattern *pattern = NULL;
    tolray_system *nominal = NULL, *built = NULL;
    tolray_status s;
    if ((s = tolray_lens_load(name, &lens)) != TOLRAY_OK) return fail(s);
    if ((s = tolray_system_new(lens, NULL, &nominal)) != TOLRAY_OK) return fail(s);
    if ((s = tolray_spec_default(&spec)) != TOLRAY_OK) return fail(s);
    if ((s = tolray_pattern_sample(spec, lens, 1, 0, &pattern)) != TOLRAY_OK) return fail(s);
    if ((s = tolray_system_new(lens, pattern, &built)) != TOLRAY_OK) return fail(s);

    const double d_line_nm = 587.5618;
    const tolray_pupil pupil = {TOLRAY_PUPIL_GRID, 32, 0, 1.0, 0};
    printf("%s (tolray %s)\n field   nominal RMS (um)   as built RMS (um)\n", name, tolray_version());
    for (int i = 0; i <= 4; i++) {
        tolray_field field = {TOLRAY_FIELD_FRACTION, 0.0, i / 4.0};
        tolray_spot_stats a, b;
        if ((s = tolray_spot(nominal, &field, &d_line_nm, 1, &pupil, 1, &a)) != TOLRAY_OK ||
            (s = tolray_spot(built, &field, &d_line_nm, 1, &pupil, 1, &b)) != TOLRAY_OK)
            return fail(s);
        printf(" %5.2f   %16.3f   %17.3f\n", field.y, a.rms_um, b.rms_um);
    }
    tolray_system_free(built);
    tolray_system_free(nominal);
    tolray_pattern_free(pattern);
    tolray_spec_free(spec);
    tolray_lens_free(lens);
    return 0;
}
