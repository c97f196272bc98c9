/*
 * The C side of `cargo bench --bench embed` (benches/embed.rs): loads a checkpoint,
 * fills the window, then times `ticks` control ticks of iastgcn_predictor_push +
 * iastgcn_predictor_predict_latest and prints the seconds they took. With a third
 * argument, each tick is timed on its own instead: the times (uint64 ns, native byte
 * order) go to that file, frames are cycled from CYCLE made beforehand, and it prints
 * "tail RSS_BEFORE RSS_AFTER FAULTS" (VmRSS in KiB after the warm-up and after the
 * run, minor page faults during it).
 *
 *   latency MODEL.safetensors TICKS [TICKS_FILE]
 */
#define _POSIX_C_SOURCE 199309L /* clock_gettime under -std=c99 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>

#include "iastgcn.h"

static double sensor(size_t node, size_t tick) {
    if (tick % (1 + node % 4) != 0) return NAN;
    size_t phase = (tick * (node + 1) * 7 + node * 13) % 200;
    return 20.0 + (double)node + 0.5 * fabs((double)phase - 100.0) / 100.0;
}

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static uint64_t now_ns(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (uint64_t)t.tv_sec * 1000000000u + (uint64_t)t.tv_nsec;
}

/* VmRSS of this process, KiB (0 where /proc has none). */
static unsigned long rss_kib(void) {
    FILE *f = fopen("/proc/self/status", "r");
    char line[256];
    unsigned long kib = 0;
    if (!f) return 0;
    while (fgets(line, sizeof line, f))
        if (strncmp(line, "VmRSS:", 6) == 0) {
            kib = strtoul(line + 6, NULL, 10);
            break;
        }
    fclose(f);
    return kib;
}

/* Minor page faults of this process so far. */
static long minor_faults(void) {
    struct rusage u;
    return getrusage(RUSAGE_SELF, &u) == 0 ? u.ru_minflt : 0;
}

#define CYCLE 1200

/* The long run: every tick timed on its own, the times written to `path`. */
static int tail(IastgcnPredictor *p, size_t nodes, size_t window, size_t ticks, const char *path) {
    double *frames = malloc(CYCLE * nodes * sizeof *frames);
    uint64_t *ns = malloc(ticks * sizeof *ns);
    if (!frames || !ns) return 1;
    for (size_t t = 0; t < CYCLE; t++)
        for (size_t n = 0; n < nodes; n++) frames[t * nodes + n] = sensor(n, t);
    /* Written before the run, so that the run touches no new page of it. */
    memset(ns, 1, ticks * sizeof *ns);
    double r[6], sum = 0.0;
    for (size_t t = 0; t < window + 10; t++) {
        iastgcn_predictor_push(p, frames + (t % CYCLE) * nodes, nodes);
        iastgcn_predictor_predict_latest(p, r);
    }
    unsigned long before = rss_kib();
    (void)now_ns(); /* the clock's pages touched before the count */
    long faults = minor_faults();
    for (size_t t = 0; t < ticks; t++) {
        uint64_t began = now_ns();
        const double *frame = frames + ((window + 10 + t) % CYCLE) * nodes;
        if (iastgcn_predictor_push(p, frame, nodes) != IASTGCN_STATUS_OK ||
            iastgcn_predictor_predict_latest(p, r) != IASTGCN_STATUS_OK) {
            fprintf(stderr, "error: %s\n", iastgcn_last_error());
            return 1;
        }
        ns[t] = now_ns() - began;
        sum += r[0];
    }
    faults = minor_faults() - faults;
    unsigned long after = rss_kib();
    FILE *f = fopen(path, "wb");
    if (!f || fwrite(ns, sizeof *ns, ticks, f) != ticks || fclose(f) != 0) {
        fprintf(stderr, "error: cannot write %s\n", path);
        return 1;
    }
    printf("tail %lu %lu %ld %g\n", before, after, faults, sum);
    free(ns);
    free(frames);
    return 0;
}

int main(int argc, char **argv) {
    if (argc < 3) {
        fprintf(stderr, "usage: latency MODEL.safetensors TICKS [TICKS_FILE]\n");
        return 2;
    }
    size_t ticks = (size_t)strtoul(argv[2], NULL, 10);
    IastgcnPredictor *p = NULL;
    if (iastgcn_predictor_load(argv[1], 0.02, IASTGCN_BACKEND_NATIVE, &p) != IASTGCN_STATUS_OK) {
        fprintf(stderr, "error: %s\n", iastgcn_last_error());
        return 1;
    }
    size_t nodes, window;
    iastgcn_predictor_shape(p, &nodes, NULL, &window);
    if (argc > 3) {
        int status = tail(p, nodes, window, ticks, argv[3]);
        iastgcn_predictor_free(p);
        return status;
    }
    /* The frames are made outside the timing, as in Rust and Python. */
    size_t total = window + 10 + ticks;
    double *frames = malloc(total * nodes * sizeof *frames);
    for (size_t t = 0; t < total; t++)
        for (size_t n = 0; n < nodes; n++) frames[t * nodes + n] = sensor(n, t);
    double r[6], sum = 0.0;
    size_t tick = 0;
    /* Fill the window (and warm up) outside the timing. */
    for (; tick < window + 10; tick++) {
        iastgcn_predictor_push(p, frames + tick * nodes, nodes);
        iastgcn_predictor_predict_latest(p, r);
    }
    double began = now();
    for (; tick < total; tick++) {
        if (iastgcn_predictor_push(p, frames + tick * nodes, nodes) != IASTGCN_STATUS_OK ||
            iastgcn_predictor_predict_latest(p, r) != IASTGCN_STATUS_OK) {
            fprintf(stderr, "error: %s\n", iastgcn_last_error());
            return 1;
        }
        sum += r[0];
    }
    double seconds = now() - began;
    printf("%.9f %g\n", seconds, sum);
    free(frames);
    iastgcn_predictor_free(p);
    return 0;
}
