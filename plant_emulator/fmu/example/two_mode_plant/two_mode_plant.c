/* A small FMI 2.0 co-simulation FMU: per channel j (1, 2) a hydraulic
 * cylinder behind a valve and a flexible link with two lightly damped
 * modes whose frequencies depend on the cylinder's extension.
 *
 *   v_j'  = (gain_j u_j - v_j) / tau                 valve lag, in/s
 *   x_j'  = v_j                                      extension, in
 *   q_jk'' + 2 zeta_k w_jk q_jk' + w_jk^2 q_jk = -b_k v_j'     k = a, b
 *   w_jk  = 2 pi f_k0 (1 + kf (x_j - x_j,start))     configuration-dependent
 *   deflection_j = q_ja + q_jb + noise_std * n       (n: seeded normal deviates)
 *
 * Integrated with classical Runge-Kutta in 1 ms internal steps; a
 * communication step that is not a whole number of them is refused
 * (fmi2Error). Fault injection for tests: at step fault_step,
 * fault_kind 1 returns fmi2Discard, 2 returns fmi2Error, 3 gives a NaN
 * deflection output for that step.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#define N_REAL 40
#define N_INT 8
#define H_INTERNAL 1e-3

enum { U1 = 0, U2, X1, X2, W1, W2, F1A, F1B, F2A, F2B, ZA_OUT, ZB_OUT };
enum { FA0 = 20, FB0, ZETA_A, ZETA_B, KF, GAIN1, GAIN2, TAU, BA, BB, X1_START, X2_START, NOISE_STD };
enum { SEED = 0, FAULT_STEP, FAULT_KIND };

typedef struct {
    double r[N_REAL];
    int i[N_INT];
    double s[2][6]; /* per channel: x, v, qa, qa', qb, qb' */
    uint64_t rng;
    long steps;
    int fault_done;
    double time;
    fmi2CallbackFunctions cb;
} Model;

static const double PI = 3.14159265358979323846;

static uint64_t next_u64(uint64_t *s) { /* xorshift64* */
    uint64_t x = *s;
    x ^= x >> 12;
    x ^= x << 25;
    x ^= x >> 27;
    *s = x;
    return x * 0x2545F4914F6CDD1DULL;
}

static double normal(uint64_t *s) { /* Box-Muller, one deviate per call */
    double a = ((next_u64(s) >> 11) + 1.0) / 9007199254740993.0;
    double b = (next_u64(s) >> 11) / 9007199254740992.0;
    return sqrt(-2.0 * log(a)) * cos(2.0 * PI * b);
}

static double omega(const Model *m, int j, int k, double x) {
    double f0 = k == 0 ? m->r[FA0] : m->r[FB0];
    double x0 = j == 0 ? m->r[X1_START] : m->r[X2_START];
    return 2.0 * PI * f0 * (1.0 + m->r[KF] * (x - x0));
}

static void deriv(const Model *m, int j, double u, const double *s, double *d) {
    double gain = j == 0 ? m->r[GAIN1] : m->r[GAIN2];
    double acc = (gain * u - s[1]) / m->r[TAU];
    d[0] = s[1];
    d[1] = acc;
    for (int k = 0; k < 2; k++) {
        double w = omega(m, j, k, s[0]);
        double z = k == 0 ? m->r[ZETA_A] : m->r[ZETA_B];
        double b = k == 0 ? m->r[BA] : m->r[BB];
        d[2 + 2 * k] = s[3 + 2 * k];
        d[3 + 2 * k] = -2.0 * z * w * s[3 + 2 * k] - w * w * s[2 + 2 * k] - b * acc;
    }
}

static void rk4(const Model *m, int j, double u, double *s, double h) {
    double k1[6], k2[6], k3[6], k4[6], t[6];
    deriv(m, j, u, s, k1);
    for (int n = 0; n < 6; n++) t[n] = s[n] + 0.5 * h * k1[n];
    deriv(m, j, u, t, k2);
    for (int n = 0; n < 6; n++) t[n] = s[n] + 0.5 * h * k2[n];
    deriv(m, j, u, t, k3);
    for (int n = 0; n < 6; n++) t[n] = s[n] + h * k3[n];
    deriv(m, j, u, t, k4);
    for (int n = 0; n < 6; n++) s[n] += h / 6.0 * (k1[n] + 2.0 * k2[n] + 2.0 * k3[n] + k4[n]);
}

static void outputs(Model *m, int nan_deflection) {
    for (int j = 0; j < 2; j++) {
        const double *s = m->s[j];
        m->r[X1 + j] = s[0];
        double noise = m->r[NOISE_STD] > 0.0 ? m->r[NOISE_STD] * normal(&m->rng) : 0.0;
        m->r[W1 + j] = nan_deflection ? NAN : s[2] + s[4] + noise;
        m->r[F1A + 2 * j] = omega(m, j, 0, s[0]) / (2.0 * PI);
        m->r[F1B + 2 * j] = omega(m, j, 1, s[0]) / (2.0 * PI);
    }
    m->r[ZA_OUT] = m->r[ZETA_A];
    m->r[ZB_OUT] = m->r[ZETA_B];
}

static void defaults(Model *m) {
    memset(m->r, 0, sizeof m->r);
    memset(m->i, 0, sizeof m->i);
    m->r[FA0] = 4.4;
    m->r[FB0] = 11.5;
    m->r[ZETA_A] = 0.05;
    m->r[ZETA_B] = 0.03;
    m->r[KF] = 0.01;
    m->r[GAIN1] = 15.0;
    m->r[GAIN2] = 7.0;
    m->r[TAU] = 0.01;
    m->r[BA] = 5.0;
    m->r[BB] = 3.0;
    m->r[X1_START] = 10.0;
    m->r[X2_START] = 10.0;
    m->r[NOISE_STD] = 0.0;
    m->i[SEED] = 0;
    m->i[FAULT_STEP] = -1;
    m->i[FAULT_KIND] = 0;
}

static void start(Model *m) {
    memset(m->s, 0, sizeof m->s);
    m->s[0][0] = m->r[X1_START];
    m->s[1][0] = m->r[X2_START];
    m->rng = 0x9E3779B97F4A7C15ULL ^ (uint64_t)(uint32_t)m->i[SEED];
    if (m->rng == 0) m->rng = 1;
    m->steps = 0;
    m->fault_done = 0;
    m->time = 0.0;
    outputs(m, 0);
}

static int valid_real(fmi2ValueReference vr) { return vr <= ZB_OUT || (vr >= FA0 && vr <= NOISE_STD); }

/* ---- FMI 2.0 ---------------------------------------------------------------------------- */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[]) { return fmi2OK; }

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String resources, const fmi2CallbackFunctions *cb,
                              fmi2Boolean visible, fmi2Boolean logging) {
    if (type != fmi2CoSimulation) return NULL;
    if (!guid || strcmp(guid, "{6f0a8b4e-2c1d-4e7a-9b3f-two-mode-plant}") != 0) return NULL;
    Model *m = (Model *)calloc(1, sizeof(Model));
    if (!m) return NULL;
    if (cb) m->cb = *cb;
    defaults(m);
    start(m);
    return m;
}

void fmi2FreeInstance(fmi2Component c) { free(c); }
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDef, fmi2Real tol, fmi2Real t0, fmi2Boolean stopDef, fmi2Real stop) {
    ((Model *)c)->time = t0;
    return fmi2OK;
}
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    double t0 = ((Model *)c)->time;
    start((Model *)c);
    ((Model *)c)->time = t0;
    return fmi2OK;
}
fmi2Status fmi2Terminate(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) {
    defaults((Model *)c);
    start((Model *)c);
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    Model *m = (Model *)c;
    for (size_t k = 0; k < n; k++) {
        if (!valid_real(vr[k])) return fmi2Error;
        value[k] = m->r[vr[k]];
    }
    return fmi2OK;
}
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    Model *m = (Model *)c;
    for (size_t k = 0; k < n; k++) {
        if (!valid_real(vr[k]) || (vr[k] > U2 && vr[k] < FA0)) return fmi2Error;
        m->r[vr[k]] = value[k];
    }
    return fmi2OK;
}
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer value[]) {
    Model *m = (Model *)c;
    for (size_t k = 0; k < n; k++) {
        if (vr[k] > FAULT_KIND) return fmi2Error;
        value[k] = m->i[vr[k]];
    }
    return fmi2OK;
}
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer value[]) {
    Model *m = (Model *)c;
    for (size_t k = 0; k < n; k++) {
        if (vr[k] > FAULT_KIND) return fmi2Error;
        m->i[vr[k]] = value[k];
    }
    return fmi2OK;
}
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean value[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean value[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String value[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String value[]) { return n ? fmi2Error : fmi2OK; }

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) { return fmi2Error; }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) { return fmi2Error; }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) { return fmi2Error; }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n) { return fmi2Error; }
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) { return fmi2Error; }
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *s) { return fmi2Error; }
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu, const fmi2ValueReference z[], size_t nz,
                                        const fmi2Real dv[], fmi2Real dz[]) {
    return fmi2Error;
}
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer o[], const fmi2Real v[]) {
    return fmi2Error;
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer o[], fmi2Real v[]) {
    return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    Model *m = (Model *)c;
    double ratio = h / H_INTERNAL;
    long n = lround(ratio);
    if (n < 1 || fabs(ratio - (double)n) > 1e-9 * ratio) {
        if (m->cb.logger)
            m->cb.logger(m->cb.componentEnvironment, "plant", fmi2Error, "error", "communication step %g s is not a whole number of 1 ms internal steps", h);
        return fmi2Error;
    }
    int fault = (m->steps == m->i[FAULT_STEP] && !m->fault_done) ? m->i[FAULT_KIND] : 0;
    if (fault) m->fault_done = 1; /* once: a repeated step is good */
    if (fault == 1) return fmi2Discard;
    if (fault == 2) return fmi2Error;
    double hi = h / (double)n;
    for (long k = 0; k < n; k++) {
        rk4(m, 0, m->r[U1], m->s[0], hi);
        rk4(m, 1, m->r[U2], m->s[1], hi);
    }
    m->steps += 1;
    m->time = t + h;
    outputs(m, fault == 3);
    return fmi2OK;
}
fmi2Status fmi2CancelStep(fmi2Component c) { return fmi2Error; }
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind k, fmi2Status *v) { return fmi2Discard; }
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind k, fmi2Real *v) {
    if (k != fmi2LastSuccessfulTime) return fmi2Discard;
    *v = ((Model *)c)->time;
    return fmi2OK;
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind k, fmi2Integer *v) { return fmi2Discard; }
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind k, fmi2Boolean *v) { return fmi2Discard; }
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind k, fmi2String *v) { return fmi2Discard; }
