/*
 * The identified spring-rod model's step, in C: the environments' stepper and the
 * engine's no-gradient step (the model packed by tensegrity_env/native/pack.py), and
 * the ground contact's forces for the PyTorch engine (tsr_contact_forces).
 *
 * This header holds what the kernel's files share: the model's layout (below), its
 * unpacked form, the SIMD vectors and the functions the files call across. The files,
 * compiled together into one library (tensegrity_env/native/build.py):
 *   native_model.c    the packed model's layout: unpacking it, its size, the limits
 *   native_forces.c   kinematics of the nodes, the springs' tensions and the rods'
 *                     explicit effects (control, drag, force field)
 *   native_contact.c  the ground contact (the step's and tsr_contact_forces)
 *   native_winch.c    the winches: loading, winding and storing their states
 *   native_step.c     Newton-Euler and the integration, the batch over threads and
 *                     the entry points tsr_step and tsr_step_groups
 *   native_sense.c    a robot's sensor readings and task error (the environments'
 *                     observation, tensegrity_env/envs/robot_sense.py)
 *
 * Exactly the physics of tensegrity_env.engine.Engine.step with the effects the
 * packing lists (tests/unit/test_envs.py and tests/unit/test_native_engine_path.py
 * check the two agree to round-off in double precision):
 *
 *   kinematics  end caps x = p + R(q) e, velocities v + w x (R e)
 *   forces      every spring a scalar tension T = K (l - l0) + c dl/dt along its
 *               axis; control h f_u at each rod's arm R r_u; ground contact per rod:
 *               four friction-pyramid edges per touching end cap, forces f >= 0
 *               from min 1/2 f'(A + R)f + f'(a0 - aref), R = (1 - d)/d 2 mu^2 (1 + mu^2) / M,
 *               by the same primal-dual active-set iteration (at most `iterations`,
 *               stop when the active set settles) and one projected Gauss-Seidel
 *               sweep: one function, vrod_contact, for the step and tsr_contact_forces
 *   accel.      a = F / M + g; Euler's equations in the rod frame with the
 *               gyroscopic term
 *   integration MuJoCo's semi-implicit Euler: v, w_local first, then p and the
 *               quaternion with the new rod-frame angular velocity
 *   winding     after the integration, each winch's speed s' = s* + (s - s*) exp(-h / tau)
 *               (s' = s* without lag), s* = clamp(u, -1, 1) v_max, then its rest length
 *               l0' = clamp(l0 + h s', l_min, l_max); the springs pull with the rest
 *               lengths of the step's start
 *
 * Only touching end caps enter the contact problem (the engine masks the others
 * out, which gives the same forces), so a rod off the floor costs nothing.
 *
 * TSR_W assemblies are stepped together, one per SIMD lane (GCC vector extensions);
 * the frame_skip substeps of a control step run with the states in registers and
 * L1, and OpenMP threads take blocks of assemblies. The library is built twice, with 8
 * lanes and with 4 (-DTSR_W=4): a batch of a few assemblies (one environment) steps
 * through the narrow one, whose shorter vectors cost less latency; the lanes never mix,
 * so both give the same numbers bit for bit (tests/unit/test_native_lanes.py).
 *
 * Layouts (all double, row-major):
 *   state   (B, R, 13): p[3] v[3] q[4] (w x y z) omega[3], world frame; in/out
 *   control (B, R, 3):  commands f_u, world frame
 *   springs (S, 2):     node indices (end caps 2r, 2r+1, then anchors, then attachment points)
 *   model:  end[R][2][3], arm_u[R][3], anchors[A][3], K[S], c[S], l0[S], mass[R],
 *           inertia[R][3], gain, gravity[3], contact[8] = {on, stiffness, damping,
 *           impedance, impedance_min, width, friction, height}, radius[R][2] (each end cap's contact radius),
 *           origin[R][3] (each rod's body-frame origin in its principal frame: the point
 *           MuJoCo's free joint integrates, tensegrity_env/engine/integration.py),
 *           sphere[R] (1: sphere end caps, whose contact frame is fixed in the world),
 *           n_points, point_rod[P], point_offset[P][3] (spring attachment points on rods
 *           besides the end caps, in their rods' principal frames),
 *           then the effects beside contact (zeros where absent): linear drag b[3],
 *           beta[3] and quadratic drag k[3], kappa[3] per rod axis (explicit, as
 *           tensegrity_env/effects/drag.py), force_field[3], the linear damping b[3],
 *           beta[3] integrated implicitly (an implicit linear drag: its wrench is among
 *           the linear drag's too; (M + h b) a = f per rod axis), and per spring the cubic
 *           stiffness k3[S] (T += k3 (l - l0)^3), rest-length offset delta[S]
 *           (T -= K delta), slack[S] (1: no elastic force while l < l0) and dry
 *           friction F[S] (T += F tanh(dl/dt / v_eps), v_eps the block's friction_velocity
 *           entry after the implicit damping, as tensegrity_env/effects/spring_friction.py),
 *           then the winches: W, winch_of[S] (1 + the winch winding spring s, 0: none),
 *           v_max[W], lag[W], l_min[W], l_max[W] (tensegrity_env/engine/winch.py)
 *   winch   (B, W, 2): each wound spring's rest length [m] and winding speed [m/s]; in/out
 *           (NULL: no winding, the rest lengths are the model's)
 *   wcmd    (B, W): the winch motors' commands, clipped to [-1, 1] (NULL: 0)
 *   groups  (tsr_step_groups): G models one after the other, and for each the first
 *           assembly it steps (assemblies start[g] .. start[g+1]-1)
 */
#ifndef TSR_NATIVE_STEP_H
#define TSR_NATIVE_STEP_H

#include <math.h>
#include <string.h>

#define TSR_MAX_RODS 16
#define TSR_MAX_NODES 64
#ifndef TSR_W
#define TSR_W 8 /* assemblies per SIMD block (the build may set 4: a narrow copy for small batches) */
#endif
#define TSR_MAX_EDGES 8
#define TSR_MAX_POINTS 32
#define TSR_MAX_WINCHES 32 /* winch states held per SIMD block on the stack (a robot has a few) */

typedef struct {
    int R, S, A;
    const double *end, *arm_u, *anchors, *K, *c, *l0, *mass, *inertia;
    double gain, g[3];
    int contact;
    double k_c, b_c, d_max, d_min, width, mu, height, soft;
    const double *radius, *origin, *sphere;
    int has_origin;
    int P, point_rod[TSR_MAX_POINTS];
    const double *point_offset;
    const double *drag, *qdrag, *field, *implicit, *cubic, *offset, *slack, *friction;
    double friction_v;
    int has_drag, has_qdrag, has_field, has_implicit, has_spring_law, has_friction;
    int W;
    const double *winch_of, *w_speed, *w_lag, *w_min, *w_max;
    const int *springs;
    int iterations;
    double dt;
} Model;

/* ------------------------------------------------------------------ W assemblies at once
 * Every quantity below is a vector of W doubles, one lane per assembly, so each
 * operation is one SIMD instruction for W assemblies. Lanes never mix: a lane's
 * result does not depend on the others (the contact iteration runs until every
 * lane has settled, and settled lanes repeat the same solve bit for bit), so an
 * assembly gives the same numbers whatever batch it is stepped in.
 */
typedef double vd __attribute__((vector_size(TSR_W * sizeof(double))));
typedef long long vl __attribute__((vector_size(TSR_W * sizeof(long long))));

static inline vd vsplat(double s) { return (vd){0} + s; }
static inline vd vsel(vl m, vd a, vd b) { return (vd)(((vl)a & m) | ((vl)b & ~m)); }
static inline vd vsqrt(vd x) {
    vd r;
    for (int l = 0; l < TSR_W; l++) r[l] = sqrt(x[l]);
    return r;
}
static inline vd vtanh(vd x) {
    vd r;
    for (int l = 0; l < TSR_W; l++) r[l] = tanh(x[l]);
    return r;
}
static inline vd vmax0(vd x) { return vsel(x > 0, x, vsplat(0.0)); }
static inline int vany(vl m) {
    long long a = 0;
    for (int l = 0; l < TSR_W; l++) a |= m[l];
    return a != 0;
}
static inline void vcross(const vd *a, const vd *b, vd *o) {
    o[0] = a[1] * b[2] - a[2] * b[1];
    o[1] = a[2] * b[0] - a[0] * b[2];
    o[2] = a[0] * b[1] - a[1] * b[0];
}
static inline vd vdot(const vd *a, const vd *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
static inline void vrotmat(const vd *q, vd *M) {
    vd w = q[0], x = q[1], y = q[2], z = q[3];
    vd ww = w * w, xx = x * x, yy = y * y, zz = z * z;
    vd xy = x * y, xz = x * z, yz = y * z, wx = w * x, wy = w * y, wz = w * z;
    M[0] = ww + xx - yy - zz; M[1] = 2 * (xy - wz);     M[2] = 2 * (xz + wy);
    M[3] = 2 * (xy + wz);     M[4] = ww - xx + yy - zz; M[5] = 2 * (yz - wx);
    M[6] = 2 * (xz - wy);     M[7] = 2 * (yz + wx);     M[8] = ww - xx - yy + zz;
}
static inline void vrot(const vd *M, const vd *v, vd *o) {
    o[0] = M[0] * v[0] + M[1] * v[1] + M[2] * v[2];
    o[1] = M[3] * v[0] + M[4] * v[1] + M[5] * v[2];
    o[2] = M[6] * v[0] + M[7] * v[1] + M[8] * v[2];
}
static inline void vrot_c(const vd *M, const double *v, vd *o) { /* constant v */
    o[0] = M[0] * v[0] + M[1] * v[1] + M[2] * v[2];
    o[1] = M[3] * v[0] + M[4] * v[1] + M[5] * v[2];
    o[2] = M[6] * v[0] + M[7] * v[1] + M[8] * v[2];
}
static inline void vrot_t(const vd *M, const vd *v, vd *o) {
    o[0] = M[0] * v[0] + M[3] * v[1] + M[6] * v[2];
    o[1] = M[1] * v[0] + M[4] * v[1] + M[7] * v[2];
    o[2] = M[2] * v[0] + M[5] * v[1] + M[8] * v[2];
}

/* sin and cos of small angles (|x| < 0.1: Taylor terms to x^10, exact in double);
 * other lanes (a rod spinning faster than 200 rad/s) go through libm */
static inline void vsincos(vd x, vd *s, vd *c) {
    vd x2 = x * x;
    *s = x * (1 + x2 * (-1.0 / 6 + x2 * (1.0 / 120 + x2 * (-1.0 / 5040 + x2 * (1.0 / 362880)))));
    *c = 1 + x2 * (-0.5 + x2 * (1.0 / 24 + x2 * (-1.0 / 720 + x2 * (1.0 / 40320 - x2 / 3628800))));
    vl big = (x > 0.1) | (x < -0.1);
    if (vany(big))
        for (int l = 0; l < TSR_W; l++)
            if (big[l]) { (*s)[l] = sin(x[l]); (*c)[l] = cos(x[l]); }
}

typedef struct { vd p[3], v[3], q[4], w[3], u[3]; } VRod;
/* the winches of W assemblies: rest length [m], winding speed [m/s], command */
typedef struct { vd rest[TSR_MAX_WINCHES], speed[TSR_MAX_WINCHES], u[TSR_MAX_WINCHES]; } VWinch;

/* functions the kernel's files call across (not exported from the library) */
#define TSR_INTERNAL __attribute__((visibility("hidden")))

/* native_model.c: the model at w (springs (S, 2) node indices); returns its length (doubles) */
TSR_INTERNAL long unpack_model(Model *m, const double *w, const int *springs, int R, int S,
                               int A);
/* native_forces.c: the node forces nf of one physics step (end caps, anchors, points) */
TSR_INTERNAL void vnode_forces(const Model *m, const VRod *x, const VWinch *wn,
                               vd M[TSR_MAX_RODS][9], vd arms[TSR_MAX_RODS][2][3],
                               vd parms[TSR_MAX_POINTS][3], vd nf[TSR_MAX_NODES][3]);
/* native_forces.c: rod r's applied wrench F, T (springs' node forces, control, drag, field) */
TSR_INTERNAL void vrod_wrench(const Model *m, int r, const VRod *xr, const vd *M,
                              vd arms[2][3], vd parms[TSR_MAX_POINTS][3],
                              vd nf[TSR_MAX_NODES][3], vd *F, vd *T);
/* native_contact.c: the contact wrench of rod r on every lane (F, T accumulate) */
TSR_INTERNAL void vcontact(const Model *m, int r, const VRod *x, const vd *M, vd arms[2][3],
                           const vd *f_s, const vd *t_s, vd *F, vd *T);
/* native_winch.c: the winches of assemblies env[0..TSR_W-1] in and out of a block, and
 * one winding step */
TSR_INTERNAL void load_winches(int NW, const long *env, const double *winch,
                               const double *wcmd, VWinch *wn);
TSR_INTERNAL void store_winches(int NW, const long *env, int lanes, const VWinch *wn,
                                double *winch);
TSR_INTERNAL void vwind(const Model *m, VWinch *wn);

#endif
