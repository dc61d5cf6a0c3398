/*
 * The identified spring-rod model's step, in C: the environments' stepper and the
 * engine's no-gradient step (the model packed by tensegrity_env/native/pack.py), and
 * the ground contact's forces for the PyTorch engine (tsr_contact_forces).
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
 * L1, and OpenMP threads take blocks of assemblies.
 *
 * Layouts (all double, row-major):
 *   state   (B, R, 13): p[3] v[3] q[4] (w x y z) omega[3], world frame; in/out
 *   control (B, R, 3):  commands f_u, world frame
 *   springs (S, 2):     node indices (end caps 2r, 2r+1, then anchors, then attachment points)
 *   model:  end[R][2][3], arm_u[R][3], anchors[A][3], K[S], c[S], l0[S], mass[R],
 *           inertia[R][3], gain, gravity[3], contact[8] = {on, stiffness, damping,
 *           impedance, impedance_min, width, friction, height}, radius[R],
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
#include <math.h>
#include <string.h>

#define TSR_MAX_RODS 16
#define TSR_MAX_NODES 64
#define TSR_W 8 /* assemblies per SIMD block */
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

/* the model at w; returns its length (doubles) */
static long unpack(Model *m, const double *w, const int *springs, int R, int S, int A) {
    const double *w0 = w;
    m->R = R; m->S = S; m->A = A; m->springs = springs;
    m->end = w; w += 6 * R;
    m->arm_u = w; w += 3 * R;
    m->anchors = w; w += 3 * A;
    m->K = w; w += S;
    m->c = w; w += S;
    m->l0 = w; w += S;
    m->mass = w; w += R;
    m->inertia = w; w += 3 * R;
    m->gain = w[0]; w += 1;
    m->g[0] = w[0]; m->g[1] = w[1]; m->g[2] = w[2]; w += 3;
    m->contact = w[0] != 0.0;
    m->k_c = w[1]; m->b_c = w[2]; m->d_max = w[3]; m->d_min = w[4];
    m->width = w[5]; m->mu = w[6]; m->height = w[7]; w += 8;
    m->soft = 2.0 * m->mu * m->mu * (1.0 + m->mu * m->mu); /* R = (1-d)/d soft / M */
    m->radius = w; w += R;
    m->origin = w;
    m->sphere = w + 3 * R;
    m->has_origin = 0;
    for (int i = 0; i < 3 * R; i++) m->has_origin |= w[i] != 0.0;
    w += 4 * R;
    m->P = (int)w[0]; w += 1;
    for (int k = 0; k < m->P && k < TSR_MAX_POINTS; k++) m->point_rod[k] = (int)w[k];
    w += m->P;
    m->point_offset = w; w += 3 * m->P;
    m->drag = w; w += 6;
    m->qdrag = w; w += 6;
    m->field = w; w += 3;
    m->implicit = w; w += 6;
    m->friction_v = w[0]; w += 1;
    m->cubic = w; w += S;
    m->offset = w; w += S;
    m->slack = w; w += S;
    m->friction = w; w += S;
    m->W = (int)w[0]; w += 1;
    m->winch_of = w; w += S;
    m->w_speed = w; w += m->W;
    m->w_lag = w; w += m->W;
    m->w_min = w; w += m->W;
    m->w_max = w; w += m->W;
    m->has_drag = m->has_qdrag = m->has_field = m->has_spring_law = m->has_implicit = 0;
    m->has_friction = 0;
    for (int i = 0; i < 6; i++) {
        m->has_drag |= m->drag[i] != 0.0;
        m->has_qdrag |= m->qdrag[i] != 0.0;
        m->has_implicit |= m->implicit[i] != 0.0;
    }
    for (int i = 0; i < 3; i++) m->has_field |= m->field[i] != 0.0;
    for (int i = 0; i < S; i++) {
        m->has_spring_law |= m->cubic[i] != 0.0 || m->offset[i] != 0.0 || m->slack[i] != 0.0;
        m->has_friction |= m->friction[i] != 0.0;
    }
    return (long)(w - w0);
}

/* the length of the packed model of R rods, S springs, A anchors, P points, W winches */
int tsr_model_size(int R, int S, int A, int P, int W) {
    return 6 * R + 3 * R + 3 * A + 3 * S + R + 3 * R + 1 + 3 + 8 + R + 4 * R + 1 + 4 * P + 22 +
           4 * S + 1 + S + 4 * W;
}

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
static void vrotmat(const vd *q, vd *M) {
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
static void vsincos(vd x, vd *s, vd *c) {
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

/* ------------------------------------------------------------------ the ground contact
 * GroundContact's law (tensegrity_env/effects/ground_contact.py), the one C form of it:
 * the kernel's step and tsr_contact_forces (the PyTorch engine's contact forces where no
 * gradient is wanted) both call vrod_contact.
 *
 * One rod on every lane. Each end cap below the floor (dist < 0) contributes four
 * friction-pyramid edges n +- mu t_1, n +- mu t_2 (t_1 along the cap's horizontal arm,
 * or y for sphere end caps); the edge forces f >= 0 minimise
 * 1/2 f'(A + R)f + f'(a0 - aref) with A = J M^-1 J', R = (1 - d)/d 2 mu^2 (1 + mu^2) / M,
 * a0 the edges' free accelerations (gravity, the applied wrench f_s, t_s, the gyroscopic
 * term and the body origin's centripetal acceleration) and aref = -b v_e - k d dist: a
 * primal-dual active-set iteration (at most m->iterations, until every lane's active set
 * settles; settled lanes repeat the same solve bit for bit) and one projected
 * Gauss-Seidel sweep. A lane with one end cap down solves 4 unknowns, a rod lying flat
 * 8 (both caps coupled through the rod); each lane's problem depends on that lane alone,
 * so an assembly gives the same numbers whatever batch it is stepped in. */

/* the contact problem of the lanes `lanes`, each with `caps` end caps down (1: the
 * touching one, cap 1 where `second`); adds the forces to fk[k] on those lanes */
static void vcontact_solve(const Model *m, int caps, vl lanes, vl second, const vd *dist,
                           vd carm[2][3], const vd *v, const vd *w, const vd *M,
                           const vd *acc, const vd *alpha, vd inv_m, const vd *isI,
                           vl sphere, vd fk[2][3]) {
    const int n = 4 * caps;
    vd garm[2][3], gdist[2], gvel[2][3], sft[2], kd[2], tx[2][2], ty[2][2];
    if (caps == 2) {
        for (int g = 0; g < 2; g++) {
            gdist[g] = dist[g];
            for (int i = 0; i < 3; i++) garm[g][i] = carm[g][i];
        }
    } else {
        gdist[0] = vsel(second, dist[1], dist[0]);
        for (int i = 0; i < 3; i++) garm[0][i] = vsel(second, carm[1][i], carm[0][i]);
    }
    for (int g = 0; g < caps; g++) {
        vd wxr[3];
        vcross(w, garm[g], wxr);
        for (int i = 0; i < 3; i++) gvel[g][i] = v[i] + wxr[i];
        vd nrm = vsqrt(garm[g][0] * garm[g][0] + garm[g][1] * garm[g][1]);
        vl ok = nrm > 1e-12;
        vd t1x = vsel(ok, garm[g][0] / nrm, vsplat(1.0));
        vd t1y = vsel(ok, garm[g][1] / nrm, vsplat(0.0));
        t1x = vsel(sphere, vsplat(0.0), t1x);
        t1y = vsel(sphere, vsplat(1.0), t1y);
        tx[g][0] = t1x; tx[g][1] = -t1y;
        ty[g][0] = t1y; ty[g][1] = t1x;
        /* impedance d(|dist|), softness and the spring term of the reference acceleration */
        vd xi = (vsel(gdist[g] < 0, -gdist[g], gdist[g])) / m->width;
        xi = vsel(xi > 1, vsplat(1.0), xi);
        vd yi = vsel(xi < 0.5, 2.0 * xi * xi, 1.0 - 2.0 * (1.0 - xi) * (1.0 - xi));
        vd d = m->d_min + yi * (m->d_max - m->d_min);
        sft[g] = (1.0 - d) / d * (m->soft * inv_m);
        kd[g] = m->k_c * d * gdist[g];
    }
    vd E[TSR_MAX_EDGES][3], Ang[TSR_MAX_EDGES][3], b[TSR_MAX_EDGES];
    for (int s = 0; s < n; s++) {
        const int g = s / 4, j = s % 4;
        double sign = (j % 2 == 0) ? 1.0 : -1.0;
        vd *e = E[s], gg[3], al[3];
        e[0] = m->mu * sign * tx[g][j / 2];
        e[1] = m->mu * sign * ty[g][j / 2];
        e[2] = vsplat(1.0);
        vcross(garm[g], e, gg);
        vrot_t(M, gg, al);
        for (int i = 0; i < 3; i++) Ang[s][i] = al[i] * isI[i];
        vd a0 = vdot(e, acc) + vdot(Ang[s], alpha);
        vd aref = -m->b_c * vdot(e, gvel[g]) - kd[g];
        b[s] = a0 - aref;
    }
    vd H[TSR_MAX_EDGES][TSR_MAX_EDGES];
    for (int i = 0; i < n; i++)
        for (int j = i; j < n; j++) {
            vd h = vdot(E[i], E[j]) * inv_m + vdot(Ang[i], Ang[j]);
            if (i == j) h += sft[i / 4];
            H[i][j] = H[j][i] = h;
        }
    /* primal-dual active set on the lanes in contact; masked Cholesky (identity off S) */
    vl S[TSR_MAX_EDGES];
    vd f[TSR_MAX_EDGES];
    for (int i = 0; i < n; i++) { S[i] = lanes & (b[i] < 0); f[i] = vsplat(0.0); }
    for (int it = 0; it < m->iterations; it++) {
        vd sd[TSR_MAX_EDGES], L[TSR_MAX_EDGES][TSR_MAX_EDGES], inv[TSR_MAX_EDGES];
        vd y[TSR_MAX_EDGES];
        for (int i = 0; i < n; i++) sd[i] = vsel(S[i], vsplat(1.0), vsplat(0.0));
        for (int j = 0; j < n; j++) {
            vd a = H[j][j] * sd[j] + (1.0 - sd[j]);
            for (int k = 0; k < j; k++) a -= L[j][k] * L[j][k];
            inv[j] = 1.0 / vsqrt(a);
            for (int i = j + 1; i < n; i++) {
                vd c = H[i][j] * (sd[i] * sd[j]);
                for (int k = 0; k < j; k++) c -= L[i][k] * L[j][k];
                L[i][j] = c * inv[j];
            }
        }
        for (int i = 0; i < n; i++) {
            vd a = -b[i] * sd[i];
            for (int k = 0; k < i; k++) a -= L[i][k] * y[k];
            y[i] = a * inv[i];
        }
        for (int i = n - 1; i >= 0; i--) {
            vd a = y[i];
            for (int k = i + 1; k < n; k++) a -= L[k][i] * f[k];
            f[i] = a * inv[i];
        }
        vl changed = (vl){0};
        vl Snew[TSR_MAX_EDGES];
        for (int i = 0; i < n; i++) {
            vd wi = b[i];
            for (int j = 0; j < n; j++) wi += H[i][j] * f[j];
            Snew[i] = lanes & ((S[i] & (f[i] > 0)) | (~S[i] & (wi < 0)));
            changed |= Snew[i] ^ S[i];
        }
        if (!vany(changed)) break;
        for (int i = 0; i < n; i++) S[i] = Snew[i];
    }
    for (int i = 0; i < n; i++) f[i] = vsel(lanes, vmax0(f[i]), vsplat(0.0));
    for (int i = 0; i < n; i++) { /* one projected Gauss-Seidel sweep */
        vd wi = b[i];
        for (int j = 0; j < n; j++) wi += H[i][j] * f[j];
        f[i] = vsel(lanes, vmax0(f[i] - wi / H[i][i]), f[i]);
    }
    for (int g = 0; g < caps; g++) {
        const int s = 4 * g;
        vd fg[3] = {f[s] * E[s][0], f[s] * E[s][1], f[s] * E[s][2]};
        for (int j = 1; j < 4; j++)
            for (int c = 0; c < 3; c++) fg[c] += f[s + j] * E[s + j][c];
        for (int c = 0; c < 3; c++) {
            if (caps == 2) {
                fk[g][c] = vsel(lanes, fg[c], fk[g][c]);
            } else {
                fk[0][c] = vsel(lanes & ~second, fg[c], fk[0][c]);
                fk[1][c] = vsel(lanes & second, fg[c], fk[1][c]);
            }
        }
    }
}

/* The contact on one rod, every lane. In, per lane: p, v, w the rod's centre of mass,
 * its velocity and angular velocity (world); M (3 x 3, body to world); arms[k] end cap
 * k's offset from the centre of mass; f_s, t_s the applied force and torque; inv_m = 1 /
 * mass, I (principal inertia) and isI = 1 / sqrt(I), radius (the end caps' contact
 * radius), sphere (sphere end caps);
 * origin the body-frame origin in the principal frame, or NULL (at the centre of mass).
 * Out: fk[k] the contact force on end cap k (0 off the floor), carm[k] its arm (contact
 * point - centre of mass). Returns whether any lane touches. */
static int vrod_contact(const Model *m, const vd *p, const vd *v, const vd *w, const vd *M,
                        vd arms[2][3], const vd *f_s, const vd *t_s, vd inv_m, const vd *I,
                        const vd *isI, vd radius, vl sphere, const vd *origin, vd fk[2][3],
                        vd carm[2][3]) {
    vd dist[2];
    vl act[2];
    for (int k = 0; k < 2; k++) {
        dist[k] = p[2] + arms[k][2] - radius - m->height;
        act[k] = dist[k] < 0;
        carm[k][0] = arms[k][0];
        carm[k][1] = arms[k][1];
        carm[k][2] = (m->height + dist[k] / 2) - p[2];
        for (int i = 0; i < 3; i++) fk[k][i] = vsplat(0.0);
    }
    if (!vany(act[0] | act[1])) return 0;
    /* free accelerations without contact: gravity, the applied wrench, gyroscopic terms */
    vd acc[3], wl[3], tl[3], Iw[3], gyro[3], alpha[3];
    for (int i = 0; i < 3; i++) acc[i] = f_s[i] * inv_m + m->g[i];
    if (origin) { /* MuJoCo's J qacc: the centripetal acceleration of the body origin */
        vd ro[3], c1[3], c2[3];
        vrot(M, origin, ro);
        vcross(w, ro, c1);
        vcross(w, c1, c2);
        for (int i = 0; i < 3; i++) acc[i] += c2[i];
    }
    vrot_t(M, w, wl);
    vrot_t(M, t_s, tl);
    for (int i = 0; i < 3; i++) Iw[i] = I[i] * wl[i];
    vcross(wl, Iw, gyro);
    for (int i = 0; i < 3; i++) alpha[i] = (tl[i] - gyro[i]) * isI[i];
    const vl one = act[0] ^ act[1], both = act[0] & act[1];
    if (vany(one))
        vcontact_solve(m, 1, one, act[1], dist, carm, v, w, M, acc, alpha, inv_m, isI, sphere, fk);
    if (vany(both))
        vcontact_solve(m, 2, both, act[1], dist, carm, v, w, M, acc, alpha, inv_m, isI, sphere,
                       fk);
    return 1;
}

/* the contact wrench of rod r on every lane (F, T accumulate); f_s, t_s: the wrench of
 * springs, control and the other effects */
static void vcontact(const Model *m, int r, const VRod *x, const vd *M, vd arms[2][3],
                     const vd *f_s, const vd *t_s, vd *F, vd *T) {
    const double *I = m->inertia + 3 * r, *o = m->origin + 3 * r;
    const vd Iv[3] = {vsplat(I[0]), vsplat(I[1]), vsplat(I[2])};
    const vd isI[3] = {vsplat(1.0 / sqrt(I[0])), vsplat(1.0 / sqrt(I[1])), vsplat(1.0 / sqrt(I[2]))};
    const vd ov[3] = {vsplat(o[0]), vsplat(o[1]), vsplat(o[2])};
    const vl sphere = vsplat(m->sphere[r]) != 0.0;
    vd fk[2][3], carm[2][3];
    if (!vrod_contact(m, x->p, x->v, x->w, M, arms, f_s, t_s, vsplat(1.0 / m->mass[r]), Iv, isI,
                      vsplat(m->radius[r]), sphere, m->has_origin ? ov : NULL, fk, carm))
        return;
    for (int k = 0; k < 2; k++) {
        vd tk[3];
        vcross(carm[k], fk[k], tk);
        for (int c = 0; c < 3; c++) { F[c] += fk[k][c]; T[c] += tk[c]; }
    }
}

/* GroundContact.contact_forces for the PyTorch engine: the contact force on every end
 * cap of B assemblies of R rods, and its arm (contact point - centre of mass), by
 * vrod_contact on W rows at a time.
 * In: p, v, omega (B, R, 3) world frame; rot (B, R, 3, 3) body to world, row-major;
 * arms (B, R, 2, 3) the end caps' offsets from the rods' centres; mass (B, R) and
 * inertia (B, R, 3) or, with per_assembly = 0, (R) and (R, 3); f_s, t_s (B, R, 3) the
 * applied wrench; radius (R); sphere (R) bytes (1: sphere end caps, contact frame t_1 =
 * y); origin (R, 3) body-frame origins or NULL; gravity[3]; law[7] = {stiffness,
 * damping, impedance, impedance_min, width, friction, height} (the model's contact
 * block without its on flag).
 * Out: force and arm (B, R, 2, 3). */
int tsr_contact_forces(long B, int R, const double *p, const double *v, const double *omega,
                       const double *rot, const double *arms, const double *mass,
                       const double *inertia, int per_assembly, const double *f_s,
                       const double *t_s, const double *radius, const unsigned char *sphere,
                       const double *origin, const double *gravity, const double *law,
                       int iterations, double *force, double *arm_out) {
    Model m;
    memset(&m, 0, sizeof(m));
    m.k_c = law[0]; m.b_c = law[1]; m.d_max = law[2];
    m.d_min = law[3]; m.width = law[4]; m.mu = law[5]; m.height = law[6];
    m.soft = 2.0 * m.mu * m.mu * (1.0 + m.mu * m.mu);
    for (int i = 0; i < 3; i++) m.g[i] = gravity[i];
    m.iterations = iterations;
    const long rows = B * R;
    for (long blk = 0; blk < rows; blk += TSR_W) {
        vd P[3], V[3], Wv[3], M[9], A[2][3], fs[3], ts[3], im, I[3], isI[3], rad, o[3];
        vl sph;
        for (int l = 0; l < TSR_W; l++) {
            const long q = blk + l < rows ? blk + l : rows - 1; /* the last block padded */
            const int r = (int)(q % R);
            const long at = per_assembly ? q : r;
            for (int i = 0; i < 3; i++) {
                P[i][l] = p[3 * q + i]; V[i][l] = v[3 * q + i]; Wv[i][l] = omega[3 * q + i];
                fs[i][l] = f_s[3 * q + i]; ts[i][l] = t_s[3 * q + i];
                A[0][i][l] = arms[6 * q + i]; A[1][i][l] = arms[6 * q + 3 + i];
                I[i][l] = inertia[3 * at + i];
                isI[i][l] = 1.0 / sqrt(inertia[3 * at + i]);
                o[i][l] = origin ? origin[3 * r + i] : 0.0;
            }
            for (int i = 0; i < 9; i++) M[i][l] = rot[9 * q + i];
            im[l] = 1.0 / mass[at];
            rad[l] = radius[r];
            sph[l] = sphere[r] ? -1 : 0;
        }
        vd fk[2][3], carm[2][3];
        vrod_contact(&m, P, V, Wv, M, A, fs, ts, im, I, isI, rad, sph, origin ? o : NULL, fk, carm);
        for (int l = 0; l < TSR_W && blk + l < rows; l++)
            for (int k = 0; k < 2; k++)
                for (int i = 0; i < 3; i++) {
                    force[6 * (blk + l) + 3 * k + i] = fk[k][i][l];
                    arm_out[6 * (blk + l) + 3 * k + i] = carm[k][i][l];
                }
    }
    return 0;
}

/* one physics step of W assemblies (R rods each); wn: their winches (NULL: none wound) */
static void vsubstep(const Model *m, VRod *x, const VWinch *wn) {
    const int R = m->R, N0 = 2 * m->R + m->A, N = N0 + m->P;
    vd M[TSR_MAX_RODS][9], arms[TSR_MAX_RODS][2][3], parms[TSR_MAX_POINTS][3];
    vd nx[TSR_MAX_NODES][3], nv[TSR_MAX_NODES][3], nf[TSR_MAX_NODES][3];
    /* kinematics: end caps and their velocities */
    for (int r = 0; r < R; r++) {
        vrotmat(x[r].q, M[r]);
        for (int k = 0; k < 2; k++) {
            vd wxa[3];
            vrot_c(M[r], m->end + 6 * r + 3 * k, arms[r][k]);
            vcross(x[r].w, arms[r][k], wxa);
            for (int i = 0; i < 3; i++) {
                nx[2 * r + k][i] = x[r].p[i] + arms[r][k][i];
                nv[2 * r + k][i] = x[r].v[i] + wxa[i];
            }
        }
    }
    for (int a = 0; a < m->A; a++)
        for (int i = 0; i < 3; i++) {
            nx[2 * R + a][i] = vsplat(m->anchors[3 * a + i]);
            nv[2 * R + a][i] = vsplat(0.0);
        }
    for (int k = 0; k < m->P; k++) { /* attachment points besides the end caps */
        const int r = m->point_rod[k];
        vd wxa[3];
        vrot_c(M[r], m->point_offset + 3 * k, parms[k]);
        vcross(x[r].w, parms[k], wxa);
        for (int i = 0; i < 3; i++) {
            nx[N0 + k][i] = x[r].p[i] + parms[k][i];
            nv[N0 + k][i] = x[r].v[i] + wxa[i];
        }
    }
    for (int n = 0; n < N; n++)
        for (int i = 0; i < 3; i++) nf[n][i] = vsplat(0.0);
    /* springs: scalar tension along each spring's axis, +T e on node a, -T e on node b */
    for (int s = 0; s < m->S; s++) {
        int a = m->springs[2 * s], b = m->springs[2 * s + 1];
        vd d[3], e[3], rate = vsplat(0.0);
        for (int i = 0; i < 3; i++) d[i] = nx[b][i] - nx[a][i];
        vd len = vsqrt(vdot(d, d)), inv = 1.0 / len;
        for (int i = 0; i < 3; i++) { e[i] = d[i] * inv; rate += (nv[b][i] - nv[a][i]) * e[i]; }
        const int wi = wn ? (int)m->winch_of[s] - 1 : -1; /* wound: the winch's rest length */
        vd stretch = wi >= 0 ? len - wn->rest[wi] : len - m->l0[s];
        vd T = m->K[s] * stretch + m->c[s] * rate;
        if (m->has_spring_law) {
            T += m->cubic[s] * (stretch * stretch * stretch) - m->K[s] * m->offset[s];
            if (m->slack[s] != 0.0) T -= vsel(stretch < 0, m->K[s] * stretch, vsplat(0.0));
        }
        if (m->has_friction && m->friction[s] != 0.0)
            T += m->friction[s] * vtanh(rate / m->friction_v);
        for (int i = 0; i < 3; i++) { nf[a][i] += T * e[i]; nf[b][i] -= T * e[i]; }
    }
    const double dt = m->dt;
    for (int r = 0; r < R; r++) {
        VRod *xr = x + r;
        vd f_s[3], t_s[3], t0[3], t1[3], F[3], T[3];
        const vd *f0 = nf[2 * r], *f1 = nf[2 * r + 1];
        vcross(arms[r][0], f0, t0);
        vcross(arms[r][1], f1, t1);
        for (int i = 0; i < 3; i++) { f_s[i] = f0[i] + f1[i]; t_s[i] = t0[i] + t1[i]; }
        for (int k = 0; k < m->P; k++) {
            if (m->point_rod[k] != r) continue;
            vd tk[3];
            vcross(parms[k], nf[N0 + k], tk);
            for (int i = 0; i < 3; i++) { f_s[i] += nf[N0 + k][i]; t_s[i] += tk[i]; }
        }
        /* control h f_u at the arm R r_u */
        vd fu[3], au[3], tu[3];
        for (int i = 0; i < 3; i++) fu[i] = m->gain * xr->u[i];
        vrot_c(M[r], m->arm_u + 3 * r, au);
        vcross(au, fu, tu);
        for (int i = 0; i < 3; i++) { F[i] = f_s[i] + fu[i]; T[i] = t_s[i] + tu[i]; }
        /* drag per rod axis (explicit) and a force field, before contact reacts */
        if (m->has_drag || m->has_qdrag) {
            vd vl_[3], wl_[3], fl[3], tq[3], fw[3], tw[3];
            vrot_t(M[r], xr->v, vl_);
            vrot_t(M[r], xr->w, wl_);
            for (int i = 0; i < 3; i++) {
                vd av = vsel(vl_[i] < 0, -vl_[i], vl_[i]), aw = vsel(wl_[i] < 0, -wl_[i], wl_[i]);
                fl[i] = -(m->drag[i] * vl_[i]) - m->qdrag[i] * (av * vl_[i]);
                tq[i] = -(m->drag[3 + i] * wl_[i]) - m->qdrag[3 + i] * (aw * wl_[i]);
            }
            vrot(M[r], fl, fw);
            vrot(M[r], tq, tw);
            for (int i = 0; i < 3; i++) { F[i] += fw[i]; T[i] += tw[i]; }
        }
        if (m->has_field)
            for (int i = 0; i < 3; i++) F[i] += m->field[i];
        /* contact is a constraint: it reacts to springs and control together */
        vd fa[3], ta[3];
        for (int i = 0; i < 3; i++) { fa[i] = F[i]; ta[i] = T[i]; }
        if (m->contact) vcontact(m, r, xr, M[r], arms[r], fa, ta, F, T);
        /* Newton-Euler */
        const double mass = m->mass[r], *I = m->inertia + 3 * r;
        vd wl[3], tl[3], Iw[3], gyro[3], acc[3], alpha[3];
        for (int i = 0; i < 3; i++) acc[i] = F[i] / mass + m->g[i];
        vrot_t(M[r], xr->w, wl);
        vrot_t(M[r], T, tl);
        for (int i = 0; i < 3; i++) Iw[i] = I[i] * wl[i];
        vcross(wl, Iw, gyro);
        for (int i = 0; i < 3; i++) alpha[i] = (tl[i] - gyro[i]) / I[i];
        if (m->has_implicit) { /* linear damping integrated implicitly, per rod axis */
            vd al_[3];
            vrot_t(M[r], acc, al_);
            for (int i = 0; i < 3; i++) {
                al_[i] = al_[i] * (mass / (mass + dt * m->implicit[i]));
                alpha[i] = alpha[i] * (I[i] / (I[i] + dt * m->implicit[3 + i]));
            }
            vrot(M[r], al_, acc);
        }
        /* semi-implicit Euler: velocities first, then positions with the new velocities;
         * of the body origin R o when it is off the centre of mass */
        vd wl2[3], ro[3];
        if (m->has_origin) {
            vd aw[3], c1[3], c2[3], c3[3];
            vrot_c(M[r], m->origin + 3 * r, ro);
            vrot(M[r], alpha, aw);
            vcross(aw, ro, c1);
            vcross(xr->w, ro, c2);
            vcross(xr->w, c2, c3);
            for (int i = 0; i < 3; i++) {
                xr->v[i] = (xr->v[i] + c2[i]) + dt * ((acc[i] + c1[i]) + c3[i]);
                xr->p[i] += ro[i];
            }
        }
        for (int i = 0; i < 3; i++) {
            if (!m->has_origin) xr->v[i] += dt * acc[i];
            wl2[i] = wl[i] + dt * alpha[i];
            xr->p[i] += dt * xr->v[i];
        }
        vd nsq = vdot(wl2, wl2);
        vl safe = nsq > 0;
        vd nrm = vsqrt(vsel(safe, nsq, vsplat(1.0))), s, c;
        vsincos(0.5 * dt * nrm, &s, &c);
        s = vsel(safe, s, vsplat(0.0));
        c = vsel(safe, c, vsplat(1.0));
        vd qr[4] = {c, wl2[0] / nrm * s, wl2[1] / nrm * s, wl2[2] / nrm * s};
        vd *q = xr->q;
        vd q2[4] = {
            q[0] * qr[0] - q[1] * qr[1] - q[2] * qr[2] - q[3] * qr[3],
            q[0] * qr[1] + q[1] * qr[0] + q[2] * qr[3] - q[3] * qr[2],
            q[0] * qr[2] - q[1] * qr[3] + q[2] * qr[0] + q[3] * qr[1],
            q[0] * qr[3] + q[1] * qr[2] - q[2] * qr[1] + q[3] * qr[0],
        };
        vd qn = vsqrt(q2[0] * q2[0] + q2[1] * q2[1] + q2[2] * q2[2] + q2[3] * q2[3]);
        for (int i = 0; i < 4; i++) q[i] = q2[i] / qn;
        vd M2[9];
        vrotmat(q, M2);
        vrot(M2, wl2, xr->w);
        if (m->has_origin) { /* back from the body origin to the centre of mass */
            vd wr[3];
            vrot_c(M2, m->origin + 3 * r, ro);
            vcross(xr->w, ro, wr);
            for (int i = 0; i < 3; i++) { xr->p[i] -= ro[i]; xr->v[i] -= wr[i]; }
        }
    }
}

/* one winding step h of the winches of W assemblies (the module's "winding") */
static void vwind(const Model *m, VWinch *wn) {
    const double h = m->dt;
    for (int k = 0; k < m->W; k++) {
        vd u = wn->u[k];
        u = vsel(u < -1.0, vsplat(-1.0), u);
        u = vsel(u > 1.0, vsplat(1.0), u);
        const vd target = u * m->w_speed[k];
        const double decay = m->w_lag[k] > 0.0 ? exp(-h / m->w_lag[k]) : 0.0;
        wn->speed[k] = target + (wn->speed[k] - target) * decay;
        vd rest = wn->rest[k] + h * wn->speed[k];
        rest = vsel(rest < m->w_min[k], vsplat(m->w_min[k]), rest);
        wn->rest[k] = vsel(rest > m->w_max[k], vsplat(m->w_max[k]), rest);
    }
}

/* frame_skip steps of assemblies lo..hi-1 under model m, W at a time (the last block
 * padded with copies of its last assembly); threads: OpenMP threads over the blocks;
 * control NULL: no command; winch NULL: no winding; wcmd NULL: the motors at 0 */
static void step_range(const Model *m, long lo, long hi, int frame_skip, double *state,
                       const double *control, double *winch, const double *wcmd,
                       int threads) {
    const int R = m->R, NW = winch ? m->W : 0;
    const long blocks = (hi - lo + TSR_W - 1) / TSR_W;
    (void)threads;
#ifdef _OPENMP
    if (threads <= 0) threads = 1;
#pragma omp parallel for schedule(dynamic, 4) num_threads(threads) if (blocks > 1 && threads > 1)
#endif
    for (long blk = 0; blk < blocks; blk++) {
        VRod x[TSR_MAX_RODS];
        VWinch wn;
        long env[TSR_W];
        for (int l = 0; l < TSR_W; l++) {
            long e = lo + blk * TSR_W + l;
            env[l] = e < hi ? e : hi - 1;
        }
        for (int r = 0; r < R; r++)
            for (int l = 0; l < TSR_W; l++) {
                const double *s = state + (env[l] * R + r) * 13;
                const double *u = control ? control + (env[l] * R + r) * 3 : NULL;
                for (int i = 0; i < 3; i++) {
                    x[r].p[i][l] = s[i];
                    x[r].v[i][l] = s[3 + i];
                    x[r].w[i][l] = s[10 + i];
                    x[r].u[i][l] = u ? u[i] : 0.0;
                }
                for (int i = 0; i < 4; i++) x[r].q[i][l] = s[6 + i];
            }
        for (int k = 0; k < NW; k++)
            for (int l = 0; l < TSR_W; l++) {
                wn.rest[k][l] = winch[(env[l] * NW + k) * 2];
                wn.speed[k][l] = winch[(env[l] * NW + k) * 2 + 1];
                wn.u[k][l] = wcmd ? wcmd[env[l] * NW + k] : 0.0;
            }
        for (int k = 0; k < frame_skip; k++) {
            vsubstep(m, x, NW ? &wn : NULL);
            if (NW) vwind(m, &wn);
        }
        for (int l = 0; l < TSR_W && lo + blk * TSR_W + l < hi; l++) {
            for (int r = 0; r < R; r++) {
                double *s = state + (env[l] * R + r) * 13;
                for (int i = 0; i < 3; i++) {
                    s[i] = x[r].p[i][l];
                    s[3 + i] = x[r].v[i][l];
                    s[10 + i] = x[r].w[i][l];
                }
                for (int i = 0; i < 4; i++) s[6 + i] = x[r].q[i][l];
            }
            for (int k = 0; k < NW; k++) {
                winch[(env[l] * NW + k) * 2] = wn.rest[k][l];
                winch[(env[l] * NW + k) * 2 + 1] = wn.speed[k][l];
            }
        }
    }
}

int tsr_step_groups(int B, int R, int S, int A, int frame_skip, double dt, int iterations,
                    double *state, const double *control, const double *models, int G,
                    const long *start, const int *springs, int threads, double *winch,
                    const double *wcmd);

/* frame_skip steps of B assemblies under one model */
int tsr_step(int B, int R, int S, int A, int frame_skip, double dt, int iterations,
             double *state, const double *control, const double *model, const int *springs,
             int threads, double *winch, const double *wcmd) {
    return tsr_step_groups(B, R, S, A, frame_skip, dt, iterations, state, control, model, 1,
                           NULL, springs, threads, winch, wcmd);
}

/* frame_skip steps of B assemblies under G models: model g (models + g * size) steps
 * assemblies start[g] .. start[g+1]-1 (start NULL: one model for all B); the winches'
 * states and commands as step_range */
int tsr_step_groups(int B, int R, int S, int A, int frame_skip, double dt, int iterations,
                    double *state, const double *control, const double *models, int G,
                    const long *start, const int *springs, int threads, double *winch,
                    const double *wcmd) {
    if (R > TSR_MAX_RODS || 2 * R + A > TSR_MAX_NODES) return -1;
    const double *w = models;
    for (int g = 0; g < G; g++) {
        Model m;
        memset(&m, 0, sizeof(m));
        const long size = unpack(&m, w, springs, R, S, A);
        if (m.P > TSR_MAX_POINTS || 2 * R + A + m.P > TSR_MAX_NODES) return -1;
        if (m.W > TSR_MAX_WINCHES || m.W < 0) return -1;
        m.iterations = iterations;
        m.dt = dt;
        long lo = start ? start[g] : 0, hi = start ? start[g + 1] : B;
        if (lo < 0 || hi > B || lo > hi) return -2;
        if (hi > lo) step_range(&m, lo, hi, frame_skip, state, control, winch, wcmd, threads);
        w += size;
    }
    return 0;
}

int tsr_max_rods(void) { return TSR_MAX_RODS; }
int tsr_max_nodes(void) { return TSR_MAX_NODES; }
int tsr_max_points(void) { return TSR_MAX_POINTS; }
int tsr_max_winches(void) { return TSR_MAX_WINCHES; }
int tsr_lanes(void) { return TSR_W; }
