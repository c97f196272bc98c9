/*
 * The C side of `cargo bench --bench embed` (benches/embed.rs): loads a checkpoint,
 * fills the window, then times `ticks` control ticks of iastgcn_predictor_push +
 * iastgcn_predictor_predict_latest and prints the seconds they took.
 *
 *   latency MODEL.safetensors TICKS
 */
#define _POSIX_C_SOURCE 199309L /* clock_gettime under -std=c99 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
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

int main(int argc, char **argv) {
    if (argc < 3) {
        fprintf(stderr, "usage: latency MODEL.safetensors TICKS\n");
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
