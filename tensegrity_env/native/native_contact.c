#include "native_step.h"

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
 * mass, I (principal inertia) and isI = 1 / sqrt(I), radius[k] (end cap k's contact
 * radius), sphere (sphere end caps);
 * origin the body-frame origin in the principal frame, or NULL (at the centre of mass).
 * Out: fk[k] the contact force on end cap k (0 off the floor), carm[k] its arm (contact
 * point - centre of mass). Returns whether any lane touches. */
static int vrod_contact(const Model *m, const vd *p, const vd *v, const vd *w, const vd *M,
                        vd arms[2][3], const vd *f_s, const vd *t_s, vd inv_m, const vd *I,
                        const vd *isI, const vd *radius, vl sphere, const vd *origin, vd fk[2][3],
                        vd carm[2][3]) {
    vd dist[2];
    vl act[2];
    for (int k = 0; k < 2; k++) {
        dist[k] = p[2] + arms[k][2] - radius[k] - m->height;
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
void vcontact(const Model *m, int r, const VRod *x, const vd *M, vd arms[2][3],
              const vd *f_s, const vd *t_s, vd *F, vd *T) {
    const double *I = m->inertia + 3 * r, *o = m->origin + 3 * r;
    const vd Iv[3] = {vsplat(I[0]), vsplat(I[1]), vsplat(I[2])};
    const vd isI[3] = {vsplat(1.0 / sqrt(I[0])), vsplat(1.0 / sqrt(I[1])), vsplat(1.0 / sqrt(I[2]))};
    const vd ov[3] = {vsplat(o[0]), vsplat(o[1]), vsplat(o[2])};
    const vl sphere = vsplat(m->sphere[r]) != 0.0;
    const vd rad[2] = {vsplat(m->radius[2 * r]), vsplat(m->radius[2 * r + 1])};
    vd fk[2][3], carm[2][3];
    if (!vrod_contact(m, x->p, x->v, x->w, M, arms, f_s, t_s, vsplat(1.0 / m->mass[r]), Iv, isI,
                      rad, sphere, m->has_origin ? ov : NULL, fk, carm))
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
 * applied wrench; radius (R, 2) each end cap's contact radius; sphere (R) bytes (1: sphere end caps, contact frame t_1 =
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
        vd P[3], V[3], Wv[3], M[9], A[2][3], fs[3], ts[3], im, I[3], isI[3], rad[2], o[3];
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
            rad[0][l] = radius[2 * r];
            rad[1][l] = radius[2 * r + 1];
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
