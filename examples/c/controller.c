/*
 * A controller loop in C: load a checkpoint once, then each control tick push the raw
 * sensor values and read the residual to compensate. It prints the same lines as the
 * Rust example (examples/controller.rs), bit for bit; tests/c_abi.rs checks it.
 *
 *   cc -std=c99 -ffp-contract=off -Iinclude examples/c/controller.c \
 *      -Ltarget/release -liastgcn -Wl,-rpath,target/release -lm -o controller
 *   ./controller MODEL.safetensors [TICKS]
 *
 * Real-time use: load before the loop; in the loop iastgcn_predictor_push and
 * iastgcn_predictor_predict_latest allocate nothing; one thread per handle.
 */
#include <inttypes.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "iastgcn.h"

/* The control period of the twin's recordings, s. */
#define DT 0.02

/* Node `node`'s sensor value at tick `tick`, or NaN when it has no new sample. */
static double sensor(size_t node, size_t tick) {
    if (tick % (1 + node % 4) != 0) return NAN;
    size_t phase = (tick * (node + 1) * 7 + node * 13) % 200;
    double triangle = fabs((double)phase - 100.0) / 100.0;
    return 20.0 + (double)node + 0.5 * triangle;
}

static uint64_t bits(double v) {
    uint64_t b;
    memcpy(&b, &v, sizeof b);
    return b;
}

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: controller MODEL.safetensors [TICKS]\n");
        return 2;
    }
    size_t ticks = argc > 2 ? (size_t)strtoul(argv[2], NULL, 10) : 60;

    IastgcnPredictor *predictor = NULL;
    if (iastgcn_predictor_load(argv[1], DT, IASTGCN_BACKEND_NATIVE, &predictor) != IASTGCN_STATUS_OK) {
        fprintf(stderr, "error: %s\n", iastgcn_last_error());
        return 1;
    }
    size_t nodes, features, window;
    iastgcn_predictor_shape(predictor, &nodes, &features, &window);
    printf("nodes %zu features %zu window %zu\n", nodes, features, window);

    double *frame = malloc(nodes * sizeof *frame);
    double r[6];
    int code = 0;
    for (size_t tick = 0; tick < ticks; tick++) {
        for (size_t node = 0; node < nodes; node++) frame[node] = sensor(node, tick);
        if (iastgcn_predictor_push(predictor, frame, nodes) != IASTGCN_STATUS_OK) {
            fprintf(stderr, "error: %s\n", iastgcn_last_error());
            code = 1;
            break;
        }
        IastgcnStatus s = iastgcn_predictor_predict_latest(predictor, r);
        if (s == IASTGCN_STATUS_NOT_READY) continue;
        if (s != IASTGCN_STATUS_OK) {
            fprintf(stderr, "error: %s\n", iastgcn_last_error());
            code = 1;
            break;
        }
        printf("tick %4zu  %9.3f %9.3f %9.3f um  %9.3f %9.3f %9.3f mdeg |", tick, r[0], r[1],
               r[2], r[3], r[4], r[5]);
        for (int k = 0; k < 6; k++) printf(" %016" PRIx64, bits(r[k]));
        printf("\n");
    }
    free(frame);
    iastgcn_predictor_free(predictor);
    return code;
}
