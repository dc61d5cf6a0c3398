/* A robot's sensor readings and its task's error, for B robots in one call: the
 * generic environments' observation (tensegrity_env/envs/robot_task.py states it in
 * NumPy, RobotSensors and the tasks' observe/error; tensegrity_env/envs/robot_sense.py
 * calls this instead where the kernel builds).
 *
 * In, per robot b: x (B, R, 13) packed rod states (p, v, q (w x y z), omega; world
 * frame), winch (B, W, 2) (rest length [m], speed), target (B, k): the goal (k = 2) or
 * the wound cables' target lengths (k = W). The robot: node_rod (N) (-1: a world
 * anchor), offsets (N, 3) (a node in its rod's principal frame, an anchor in the
 * world), springs (S, 2) node indices, wound (W) the spring each winch winds.
 * Out: obs (B, 6R + 1 + S + W + k) float32: end caps minus their mean c, c's height,
 * every cable's length, the winches' rest lengths, then the goal minus the rods' centre
 * (x, y) or the target minus each wound cable's length; error (B): the centre's
 * horizontal distance to the goal, or the largest absolute length error [m]; centre
 * (B, 3): the mean of the rod centres [m].
 *
 * The sums run in NumPy's order and nothing is fused into a multiply-add, so the rods'
 * centre, the goal distance and (rounded to float32) the readings are NumPy's own bit for
 * bit (tests/unit/test_robot_sense.py). */
#if defined(__clang__)
#pragma STDC FP_CONTRACT OFF
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif
#include "native_step.h"

#define TSR_TASK_GOAL 0
#define TSR_TASK_SHAPE 1

/* the length of spring s between its nodes [m] */
static double cable_length(double node[][3], const int *springs, int s) {
    const double *a = node[springs[2 * s]], *z = node[springs[2 * s + 1]];
    const double d0 = a[0] - z[0], d1 = a[1] - z[1], d2 = a[2] - z[2];
    return sqrt(d0 * d0 + d1 * d1 + d2 * d2);
}

int tsr_sense(long B, int R, int N, int S, int W, int task, const double *x,
              const double *winch, const double *target, const int *node_rod,
              const double *offsets, const int *springs, const int *wound, float *obs,
              double *error, double *centre) {
    if (R < 1 || R > TSR_MAX_RODS || N < 2 * R || N > TSR_MAX_NODES || S < 0 || W < 0 ||
        W > TSR_MAX_WINCHES || (task != TSR_TASK_GOAL && task != TSR_TASK_SHAPE))
        return -1;
    const int k = task == TSR_TASK_GOAL ? 2 : W, n_obs = 6 * R + 1 + S + W + k;
    for (long b = 0; b < B; b++) {
        const double *xb = x + b * R * 13;
        float *o = obs + b * n_obs;
        double M[TSR_MAX_RODS][9], node[TSR_MAX_NODES][3];
        for (int r = 0; r < R; r++) { /* body to world, as MuJoCo's mju_quat2Mat */
            const double *q = xb + 13 * r + 6, w = q[0], qx = q[1], qy = q[2], qz = q[3];
            double *m = M[r];
            m[0] = w * w + qx * qx - qy * qy - qz * qz;
            m[1] = 2 * (qx * qy - w * qz);
            m[2] = 2 * (qx * qz + w * qy);
            m[3] = 2 * (qx * qy + w * qz);
            m[4] = w * w - qx * qx + qy * qy - qz * qz;
            m[5] = 2 * (qy * qz - w * qx);
            m[6] = 2 * (qx * qz - w * qy);
            m[7] = 2 * (qy * qz + w * qx);
            m[8] = w * w - qx * qx - qy * qy + qz * qz;
        }
        for (int n = 0; n < N; n++) {
            const int r = node_rod[n];
            const double *e = offsets + 3 * n;
            for (int i = 0; i < 3; i++)
                node[n][i] = r < 0 ? e[i]
                                   : xb[13 * r + i] + (M[r][3 * i] * e[0] + M[r][3 * i + 1] * e[1] +
                                                       M[r][3 * i + 2] * e[2]);
        }
        double c[3], rc[3]; /* the end caps' mean, the rods' centre: sums in order */
        for (int i = 0; i < 3; i++) {
            c[i] = node[0][i];
            for (int j = 1; j < 2 * R; j++) c[i] += node[j][i];
            c[i] = c[i] / (2 * R);
            rc[i] = xb[i];
            for (int r = 1; r < R; r++) rc[i] += xb[13 * r + i];
            rc[i] = rc[i] / R;
            centre[3 * b + i] = rc[i];
        }
        for (int j = 0; j < 2 * R; j++)
            for (int i = 0; i < 3; i++) o[3 * j + i] = (float)(node[j][i] - c[i]);
        o[6 * R] = (float)c[2];
        for (int s = 0; s < S; s++) o[6 * R + 1 + s] = (float)cable_length(node, springs, s);
        for (int w = 0; w < W; w++) o[6 * R + 1 + S + w] = (float)winch[(b * W + w) * 2];
        float *tail = o + 6 * R + 1 + S + W;
        const double *t = target + b * k;
        if (task == TSR_TASK_GOAL) {
            const double gx = t[0] - rc[0], gy = t[1] - rc[1];
            tail[0] = (float)gx;
            tail[1] = (float)gy;
            error[b] = sqrt(gx * gx + gy * gy);
        } else {
            double worst = 0.0;
            for (int w = 0; w < W; w++) {
                const double gap = t[w] - cable_length(node, springs, wound[w]);
                tail[w] = (float)gap;
                const double mag = fabs(gap);
                worst = w == 0 || mag > worst || mag != mag ? mag : worst; /* NaN stays */
            }
            error[b] = worst;
        }
    }
    return 0;
}
