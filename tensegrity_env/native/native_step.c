/*
 * The kernel's step (the model and the layouts: native_step.h): Newton-Euler and
 * MuJoCo's semi-implicit Euler for every rod after the forces (native_forces.c) and the
 * contact (native_contact.c), the winding after the integration (native_winch.c), the
 * frame_skip substeps of W assemblies in registers and L1, OpenMP threads over blocks
 * of assemblies, and the entry points tsr_step and tsr_step_groups.
 */
#include "native_step.h"

/* one physics step of W assemblies (R rods each); wn: their winches (NULL: none wound) */
static void vsubstep(const Model *m, VRod *x, const VWinch *wn) {
    const int R = m->R;
    vd M[TSR_MAX_RODS][9], arms[TSR_MAX_RODS][2][3], parms[TSR_MAX_POINTS][3];
    vd nf[TSR_MAX_NODES][3];
    vnode_forces(m, x, wn, M, arms, parms, nf);
    const double dt = m->dt;
    for (int r = 0; r < R; r++) {
        VRod *xr = x + r;
        vd F[3], T[3];
        vrod_wrench(m, r, xr, M[r], arms[r], parms, nf, F, T);
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
        load_winches(NW, env, winch, wcmd, &wn);
        for (int k = 0; k < frame_skip; k++) {
            vsubstep(m, x, NW ? &wn : NULL);
            if (NW) vwind(m, &wn);
        }
        const long left = hi - (lo + blk * TSR_W);
        const int lanes = left < TSR_W ? (int)left : TSR_W;
        for (int l = 0; l < lanes; l++)
            for (int r = 0; r < R; r++) {
                double *s = state + (env[l] * R + r) * 13;
                for (int i = 0; i < 3; i++) {
                    s[i] = x[r].p[i][l];
                    s[3 + i] = x[r].v[i][l];
                    s[10 + i] = x[r].w[i][l];
                }
                for (int i = 0; i < 4; i++) s[6 + i] = x[r].q[i][l];
            }
        store_winches(NW, env, lanes, &wn, winch);
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
        const long size = unpack_model(&m, w, springs, R, S, A);
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
