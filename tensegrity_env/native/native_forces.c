/* One physics step's forces before the contact reacts: the nodes' kinematics, every
 * spring's scalar tension along its axis (the winches' rest lengths for the wound ones,
 * the cubic law, offset, slack and dry friction), and each rod's applied wrench (the
 * springs' node forces, control h f_u, explicit drag, a force field). */
#include "native_step.h"

/* the node forces nf (end caps 2r, 2r+1, then anchors, then attachment points) of W
 * assemblies, and what the rods' wrenches need: each rod's rotation M (body to world),
 * its end caps' arms and the attachment points' arms parms; wn: the winches (NULL: none
 * wound) */
void vnode_forces(const Model *m, const VRod *x, const VWinch *wn, vd M[TSR_MAX_RODS][9],
                  vd arms[TSR_MAX_RODS][2][3], vd parms[TSR_MAX_POINTS][3],
                  vd nf[TSR_MAX_NODES][3]) {
    const int R = m->R, N0 = 2 * m->R + m->A, N = N0 + m->P;
    vd nx[TSR_MAX_NODES][3], nv[TSR_MAX_NODES][3];
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
}

/* rod r's wrench F, T [N, N m] on every lane before the contact: its nodes' spring forces
 * (nf, arms, parms from vnode_forces), control h f_u at the arm R r_u, drag per rod axis
 * and a force field */
void vrod_wrench(const Model *m, int r, const VRod *xr, const vd *M, vd arms[2][3],
                 vd parms[TSR_MAX_POINTS][3], vd nf[TSR_MAX_NODES][3], vd *F, vd *T) {
    const int N0 = 2 * m->R + m->A;
    vd f_s[3], t_s[3], t0[3], t1[3];
    const vd *f0 = nf[2 * r], *f1 = nf[2 * r + 1];
    vcross(arms[0], f0, t0);
    vcross(arms[1], f1, t1);
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
    vrot_c(M, m->arm_u + 3 * r, au);
    vcross(au, fu, tu);
    for (int i = 0; i < 3; i++) { F[i] = f_s[i] + fu[i]; T[i] = t_s[i] + tu[i]; }
    /* drag per rod axis (explicit) and a force field, before contact reacts */
    if (m->has_drag || m->has_qdrag) {
        vd vl_[3], wl_[3], fl[3], tq[3], fw[3], tw[3];
        vrot_t(M, xr->v, vl_);
        vrot_t(M, xr->w, wl_);
        for (int i = 0; i < 3; i++) {
            vd av = vsel(vl_[i] < 0, -vl_[i], vl_[i]), aw = vsel(wl_[i] < 0, -wl_[i], wl_[i]);
            fl[i] = -(m->drag[i] * vl_[i]) - m->qdrag[i] * (av * vl_[i]);
            tq[i] = -(m->drag[3 + i] * wl_[i]) - m->qdrag[3 + i] * (aw * wl_[i]);
        }
        vrot(M, fl, fw);
        vrot(M, tq, tw);
        for (int i = 0; i < 3; i++) { F[i] += fw[i]; T[i] += tw[i]; }
    }
    if (m->has_field)
        for (int i = 0; i < 3; i++) F[i] += m->field[i];
}
