/*
 * Normal equations of the spring-rod regression, straight from the rod states.
 *
 * For every selected transition t -> t+1 and every rod r this computes the rod's
 * 6 x L local design block of identification/linear/design.py (rod_blocks) and adds its
 * Gram matrix (upper triangle) into out[r] (L x L). It never stores the block: the
 * block's columns are products of a few 6-vectors ("bases") and scalars,
 *
 *   column 0           : [a - g ; 0]                         (mass)
 *   column 1 + k       : [0 ; alpha_k e_k + w x (e_k w_k)]   (inertia, k = x, y, z)
 *   column 4 + 3 j + m : [f_j ; t_j] * s_jm                  (spring slot j: K, K l0, c)
 *   column L - 1       : [-f_u ; -R^T (r_u x f_u)]           (control gain)
 *
 * with f_j = sign * axis (world), t_j = R^T (arm x f_j) (rod frame, arm: the lever of
 * the node where the rod holds spring j, an end cap or any attachment point) and
 * s_j = (-l, 1, -ldot) (or (-(l - l0), 0, -ldot) when rest lengths are known),
 * so the Gram is H[b(c)][b(c')] * s(c) * s(c') with H the 6-D Gram of the 5 + J bases.
 * Same conventions as the PyTorch path (features.py, design.py): quaternions w, x, y, z;
 * omega in the world frame; MuJoCo's rotation matrix; accelerations by differences.
 *
 * Layout (C order, float64 unless said):
 *   p, v, omega: (n_traj, T + 1, R, 3); q: (n_traj, T + 1, R, 4); control: (n_traj, T, R, 3)
 *   index: (n_index,) int64 flat transition indices traj * T + t
 *   node_rod: (N,) int32, the rod owning each node or -1 for a world anchor; node_offsets:
 *   (N, 3), each node in its rod's frame (anchors: world position); spring_nodes: (S, 2) int32
 *   control_arms: (R, 3); slot_spring, slot_node: (R, J) int32; slot_sign: (R, J)
 *   gravity: (3,); rest_length: (S,) or NULL; frame_origins: (R, 3) body-frame origins in
 *   the rod frame, or NULL when every body frame is at the COM (accelerations as in
 *   tensegrity_env/engine/integration.py step_accelerations); out: (R, L, L) accumulated,
 *   L = 5 + 3 J
 * Returns 0, or -1 when a size is beyond the fixed limits below.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#ifdef _OPENMP
#include <omp.h>
#endif

#define MAX_RODS 64
#define MAX_SLOTS 32
#define MAX_NODES (2 * MAX_RODS + 64)
#define MAX_SPRINGS 512
#define MAX_BASES (5 + MAX_SLOTS)
#define CHUNK 512 /* transitions summed locally before adding to the total */

int tsr_normal_max_rods(void) { return MAX_RODS; }
int tsr_normal_max_slots(void) { return MAX_SLOTS; }
int tsr_normal_max_springs(void) { return MAX_SPRINGS; }
int tsr_normal_max_nodes(void) { return MAX_NODES; }

static void quat_to_matrix(const double *q, double *m) {
    const double w = q[0], x = q[1], y = q[2], z = q[3];
    const double ww = w * w, xx = x * x, yy = y * y, zz = z * z;
    const double xy = x * y, xz = x * z, yz = y * z, wx = w * x, wy = w * y, wz = w * z;
    m[0] = ww + xx - yy - zz; m[1] = 2 * (xy - wz);      m[2] = 2 * (xz + wy);
    m[3] = 2 * (xy + wz);     m[4] = ww - xx + yy - zz;  m[5] = 2 * (yz - wx);
    m[6] = 2 * (xz - wy);     m[7] = 2 * (yz + wx);      m[8] = ww - xx - yy + zz;
}

static inline void mat_vec(const double *m, const double *a, double *o) {
    o[0] = m[0] * a[0] + m[1] * a[1] + m[2] * a[2];
    o[1] = m[3] * a[0] + m[4] * a[1] + m[5] * a[2];
    o[2] = m[6] * a[0] + m[7] * a[1] + m[8] * a[2];
}

static inline void mat_t_vec(const double *m, const double *a, double *o) {
    o[0] = m[0] * a[0] + m[3] * a[1] + m[6] * a[2];
    o[1] = m[1] * a[0] + m[4] * a[1] + m[7] * a[2];
    o[2] = m[2] * a[0] + m[5] * a[1] + m[8] * a[2];
}

static inline void cross(const double *a, const double *b, double *o) {
    o[0] = a[1] * b[2] - a[2] * b[1];
    o[1] = a[2] * b[0] - a[0] * b[2];
    o[2] = a[0] * b[1] - a[1] * b[0];
}

typedef struct {
    int n_traj, T, R, N, S, J;
    const double *p, *v, *q, *w, *u;
    const double *node_offsets, *control_arms, *slot_sign, *gravity, *rest, *origins;
    const int *node_rod, *spring_nodes, *slot_spring, *slot_node;
    double dt;
} Problem;

/* Add the Gram of every rod's block for one transition into acc (R, L, L). */
static void add_transition(const Problem *P, int64_t flat, double *acc) {
    const int R = P->R, J = P->J, L = 5 + 3 * J, nb = 5 + J;
    const int64_t traj = flat / P->T, t = flat % P->T;
    const int64_t s0 = (traj * (P->T + 1) + t) * R, s1 = s0 + R;
    double rot[MAX_RODS][9], arm[MAX_NODES][3];
    double x[MAX_NODES][3], xd[MAX_NODES][3];
    double len[MAX_SPRINGS], rate[MAX_SPRINGS], axis[MAX_SPRINGS][3];

    for (int r = 0; r < R; r++) quat_to_matrix(P->q + 4 * (s0 + r), rot[r]);
    for (int n = 0; n < P->N; n++) {
        const int r = P->node_rod[n];
        const double *off = P->node_offsets + 3 * n;
        if (r < 0) { /* a world anchor */
            for (int i = 0; i < 3; i++) { x[n][i] = off[i]; xd[n][i] = 0.0; arm[n][i] = 0.0; }
            continue;
        }
        const double *pr = P->p + 3 * (s0 + r), *vr = P->v + 3 * (s0 + r);
        const double *wr = P->w + 3 * (s0 + r);
        double wxa[3];
        mat_vec(rot[r], off, arm[n]);
        cross(wr, arm[n], wxa);
        for (int i = 0; i < 3; i++) {
            x[n][i] = pr[i] + arm[n][i];
            xd[n][i] = vr[i] + wxa[i];
        }
    }
    for (int s = 0; s < P->S; s++) {
        const int na = P->spring_nodes[2 * s], nbn = P->spring_nodes[2 * s + 1];
        double d[3], n2 = 0.0, rt = 0.0;
        for (int i = 0; i < 3; i++) { d[i] = x[nbn][i] - x[na][i]; n2 += d[i] * d[i]; }
        len[s] = sqrt(n2);
        for (int i = 0; i < 3; i++) {
            axis[s][i] = d[i] / len[s];
            rt += (xd[nbn][i] - xd[na][i]) * axis[s][i];
        }
        rate[s] = rt;
    }

    for (int r = 0; r < R; r++) {
        double B[MAX_BASES][6], H[MAX_BASES][MAX_BASES];
        double scal[MAX_SLOTS][3];
        const double *v0 = P->v + 3 * (s0 + r), *v1 = P->v + 3 * (s1 + r);
        const double *w0 = P->w + 3 * (s0 + r), *w1 = P->w + 3 * (s1 + r);
        double rot1[9], wl0[3], wl1[3], alpha[3];
        quat_to_matrix(P->q + 4 * (s1 + r), rot1);
        mat_t_vec(rot[r], w0, wl0);
        mat_t_vec(rot1, w1, wl1);
        memset(B, 0, sizeof(double) * 6 * nb);
        for (int i = 0; i < 3; i++) {
            alpha[i] = (wl1[i] - wl0[i]) / P->dt;
            B[0][i] = (v1[i] - v0[i]) / P->dt - P->gravity[i];
        }
        if (P->origins) { /* the body origin o integrates, not the COM (integration.py) */
            double r0[3], r1[3], c0[3], c1[3], aw[3], t0[3], t1[3];
            mat_vec(rot[r], P->origins + 3 * r, r0);
            mat_vec(rot1, P->origins + 3 * r, r1);
            mat_vec(rot[r], alpha, aw);
            cross(w0, r0, c0);
            cross(w1, r1, c1);
            cross(aw, r0, t0);
            cross(w0, c0, t1);
            for (int i = 0; i < 3; i++)
                B[0][i] = ((v1[i] + c1[i]) - (v0[i] + c0[i])) / P->dt - t0[i] - t1[i]
                          - P->gravity[i];
        }
        for (int k = 0; k < 3; k++) {  /* alpha_k e_k + w x (e_k w_k) */
            double ek[3] = {0.0, 0.0, 0.0}, c[3];
            ek[k] = wl0[k];
            cross(wl0, ek, c);
            for (int i = 0; i < 3; i++) B[1 + k][3 + i] = c[i];
            B[1 + k][3 + k] += alpha[k];
        }
        for (int j = 0; j < J; j++) {
            const double sg = P->slot_sign[r * J + j];
            const int s = P->slot_spring[r * J + j], nd = P->slot_node[r * J + j];
            double f[3], tw[3];
            for (int i = 0; i < 3; i++) f[i] = sg * axis[s][i];
            cross(arm[nd], f, tw);
            for (int i = 0; i < 3; i++) B[4 + j][i] = f[i];
            mat_t_vec(rot[r], tw, &B[4 + j][3]);
            scal[j][0] = P->rest ? -(len[s] - P->rest[s]) : -len[s];
            scal[j][1] = P->rest ? 0.0 : 1.0;
            scal[j][2] = -rate[s];
        }
        {
            const double *fu = P->u + 3 * (flat * R + r);
            double armu[3], tw[3];
            mat_vec(rot[r], P->control_arms + 3 * r, armu);
            cross(armu, fu, tw);
            for (int i = 0; i < 3; i++) B[4 + J][i] = -fu[i];
            mat_t_vec(rot[r], tw, &B[4 + J][3]);
            for (int i = 0; i < 3; i++) B[4 + J][3 + i] = -B[4 + J][3 + i];
        }
        for (int a = 0; a < nb; a++)
            for (int b = a; b < nb; b++) {
                double h = 0.0;
                for (int i = 0; i < 6; i++) h += B[a][i] * B[b][i];
                H[a][b] = h;
            }

        /* column c -> (basis, scalar): bases 0..3 and 4 + J carry one column of factor 1 */
        double *G = acc + (size_t)r * L * L;
        int base_of[3 * MAX_SLOTS + 5];
        double fac[3 * MAX_SLOTS + 5];
        for (int c = 0; c < 4; c++) { base_of[c] = c; fac[c] = 1.0; }
        for (int j = 0; j < J; j++)
            for (int m = 0; m < 3; m++) { base_of[4 + 3 * j + m] = 4 + j; fac[4 + 3 * j + m] = scal[j][m]; }
        base_of[L - 1] = 4 + J;
        fac[L - 1] = 1.0;
        for (int c = 0; c < L; c++) {
            const double *Hrow = H[base_of[c]];
            const double fc = fac[c];
            double *Grow = G + (size_t)c * L;
            for (int d = c; d < L; d++) {
                const int bc = base_of[c], bd = base_of[d];
                const double h = bc <= bd ? Hrow[bd] : H[bd][bc];
                Grow[d] += h * fc * fac[d];
            }
        }
    }
}

int tsr_normal(int n_traj, int T, int R, int N, int S, int J,
               const double *p, const double *v, const double *q, const double *w,
               const double *control, const int64_t *index, int64_t n_index,
               const int *node_rod, const double *node_offsets, const int *spring_nodes,
               const double *control_arms, const int *slot_spring, const int *slot_node,
               const double *slot_sign, const double *gravity, const double *rest_length,
               const double *frame_origins, double dt, int n_threads, double *out) {
    if (R > MAX_RODS || J > MAX_SLOTS || S > MAX_SPRINGS || N > MAX_NODES) return -1;
    const Problem P = {n_traj, T, R, N, S, J, p, v, q, w, control, node_offsets,
                       control_arms, slot_sign, gravity, rest_length, frame_origins, node_rod,
                       spring_nodes, slot_spring, slot_node, dt};
    const int L = 5 + 3 * J;
    const size_t size = (size_t)R * L * L;
    const int64_t n_chunks = (n_index + CHUNK - 1) / CHUNK;
    (void)n_threads;
#ifdef _OPENMP
#pragma omp parallel num_threads(n_threads > 0 ? n_threads : 1)
#endif
    {
        double *total = calloc(size, sizeof(double));
        double *part = calloc(size, sizeof(double));
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
        for (int64_t c = 0; c < n_chunks; c++) {
            const int64_t end = (c + 1) * CHUNK < n_index ? (c + 1) * CHUNK : n_index;
            memset(part, 0, size * sizeof(double));
            for (int64_t i = c * CHUNK; i < end; i++) add_transition(&P, index[i], part);
            for (size_t k = 0; k < size; k++) total[k] += part[k];
        }
#ifdef _OPENMP
#pragma omp critical
#endif
        for (size_t k = 0; k < size; k++) out[k] += total[k];
        free(total);
        free(part);
    }
    return 0;
}
