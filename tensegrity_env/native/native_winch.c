/* The winches (tensegrity_env/engine/winch.py): their states in and out of a SIMD block,
 * and one winding step after the integration (native_step.h, "winding"). */
#include "native_step.h"

/* the winch states (B, W, 2) and commands (B, W) (NULL: 0) of assemblies env[l] into wn */
void load_winches(int NW, const long *env, const double *winch, const double *wcmd,
                  VWinch *wn) {
    for (int k = 0; k < NW; k++)
        for (int l = 0; l < TSR_W; l++) {
            wn->rest[k][l] = winch[(env[l] * NW + k) * 2];
            wn->speed[k][l] = winch[(env[l] * NW + k) * 2 + 1];
            wn->u[k][l] = wcmd ? wcmd[env[l] * NW + k] : 0.0;
        }
}

/* the first `lanes` lanes' winch states back into winch (B, W, 2) */
void store_winches(int NW, const long *env, int lanes, const VWinch *wn, double *winch) {
    for (int l = 0; l < lanes; l++)
        for (int k = 0; k < NW; k++) {
            winch[(env[l] * NW + k) * 2] = wn->rest[k][l];
            winch[(env[l] * NW + k) * 2 + 1] = wn->speed[k][l];
        }
}

/* one winding step h of the winches of W assemblies (native_step.h, "winding") */
void vwind(const Model *m, VWinch *wn) {
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
