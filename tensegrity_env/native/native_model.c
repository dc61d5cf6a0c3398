/* The packed model's layout (native_step.h): unpacking it, its size, the kernel's limits. */
#include "native_step.h"

/* the model at w; returns its length (doubles) */
long unpack_model(Model *m, const double *w, const int *springs, int R, int S, int A) {
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
    m->radius = w; w += 2 * R;
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

int tsr_max_rods(void) { return TSR_MAX_RODS; }
int tsr_max_nodes(void) { return TSR_MAX_NODES; }
int tsr_max_points(void) { return TSR_MAX_POINTS; }
int tsr_max_winches(void) { return TSR_MAX_WINCHES; }
int tsr_lanes(void) { return TSR_W; }
