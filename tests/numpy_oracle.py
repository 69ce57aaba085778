"""Plain NumPy reference implementation (test oracle) of the closed-loop simulation in

    M.-C. Hwang and X. Hu, "A Robust Position/Force Learning Controller of Manipulators
    via Nonlinear H-infinity Control and Neural Networks", Sec. VI,

with the corrections and conventions of docs/paper-conventions.md.

This file is deliberately written plainly and independently of the ``hinfnn`` library:
explicit matrices, numpy.linalg.inv / numpy.linalg.solve, and a Python for-loop over
fixed RK4 steps.  It is meant to be read next to the paper, one function per paper block.

Controllers
    "fl"       feedback-linearization-like law of Sec. VI (with u1d_ddot, docs/paper-conventions.md, printed errors),
    "hinf"     H-infinity-only law, Theorem 2 / eq. (51),
    "hinf_nn"  adaptive H-infinity NN law, Theorem 1, eqs. (24)-(33).

State layout (166 entries)
    y = [q1, q2, qd1, qd2, z, theta_p (40), theta_f (120), J]

Conventions used (see docs/paper-conventions.md):
  * Coriolis matrix entry (2,1) is +qd1 (printed -qd1 is an erratum).
  * Eq. (9): Mbar = S^T Jh^-T Mh Jh^-1 S and Gbar = S^T Jh^-T Gh (printed forms are errata).
  * Constraint, "paper" scaling: theta(x) = (x1 - dG) tan(dh) - x2, A = [tan dh, -1],
    Sigma = tan dh, Pi = -1.  "unit" scaling: theta = (x1 - dG) sin dh - x2 cos dh,
    A = [sin dh, -cos dh], Sigma = sin dh, Pi = -cos dh.  In both Gamma = tan dh.
  * F is the force the end-effector exerts on the surface; it enters eq. (1) as +J^T F.
  * lambda measured = A F / (A A^T) with the NOMINAL gradient A.
"""

import math
import time

import numpy as np
import scipy.linalg


# ---------------------------------------------------------------------------------------
# Parameters of Sec. VI
# ---------------------------------------------------------------------------------------

PAPER = {
    # true plant
    "m1": 1.2,
    "m2": 1.1,
    "l1": 1.02724,
    "l2": 0.98041,
    "g": 9.8,
    "delta": 91.0 * math.pi / 360.0,
    "d_G": 0.8,
    "k_contact": 1e5,
    "c_contact": 0.0,
    # nominal model used by the controller
    "m1_nom": 1.5,
    "m2_nom": 1.0,
    "l1_nom": 1.0,
    "l2_nom": 1.0,
    "delta_nom": math.pi / 4.0,
    "d_G_nom": 0.8,
    "g_nom": 9.8,
    # gains
    "rho": 0.6,
    "mu_z": 100.0,
    "K_p": 18.0,
    "K_v": 9.0,
    "alpha_lam": 1.0,
    "alpha_z": 2.0,
    "beta_lam": 1.0 / 0.6 ** 2 - 1.0,  # = alpha_lam / rho**2 - 1, Theorem 1 minimum
    "gamma_1": 2.0,
    "gamma_2": 2.0,
    "Q_p": np.eye(2),
    "R_p": 0.495,
    # neural networks, eq. (17)-(19) and Sec. VI
    "centres_p_start": -1.0,
    "centres_p_step": 0.05,
    "centres_p_count": 40,
    "centres_f_start": -30.0,
    "centre_step_f": 0.5,
    "centres_f_count": 120,
    "slope": 1.0,
    # disturbance (square wave on both joints)
    "dist_amp": 3.0,
    "dist_period": 1.0,
    "dist_phase": 0.0,
    # constraint scaling: "paper" or "unit"
    "scaling": "paper",
    # initial condition
    "u1_0": 1.6902,
}

N_P = 40
N_F = 120
IDX_Q = slice(0, 2)
IDX_QD = slice(2, 4)
IDX_Z = 4
IDX_THP = slice(5, 5 + N_P)
IDX_THF = slice(5 + N_P, 5 + N_P + N_F)
IDX_J = 5 + N_P + N_F
N_STATE = IDX_J + 1  # 166

CONTROLLERS = ("fl", "hinf", "hinf_nn")


def _merge(params):
    if params is None:
        return dict(PAPER)
    return {**PAPER, **params}


# ---------------------------------------------------------------------------------------
# Arm model, Sec. VI (eq. (1) matrices)
# ---------------------------------------------------------------------------------------

def arm_matrices(q, qd, m1, m2, l1, l2, g):
    """Sec. VI: inertia M(q), Coriolis matrix C(q, qd) (entry (2,1) = +qd1, docs/paper-conventions.md, printed errors)
    and gravity G(q) of the planar two-link arm in eq. (1)."""
    c1 = math.cos(q[0])
    c2 = math.cos(q[1])
    s2 = math.sin(q[1])
    c12 = math.cos(q[0] + q[1])
    M = np.array([
        [(m1 + m2) * l1 ** 2 + m2 * l2 ** 2 + 2.0 * m2 * l1 * l2 * c2,
         m2 * l2 ** 2 + m2 * l1 * l2 * c2],
        [m2 * l2 ** 2 + m2 * l1 * l2 * c2,
         m2 * l2 ** 2],
    ])
    hc = m2 * l1 * l2 * s2
    C = hc * np.array([
        [-qd[1], -(qd[0] + qd[1])],
        [qd[0], 0.0],
    ])
    G = g * np.array([
        (m1 + m2) * l1 * c1 + m2 * l2 * c12,
        m2 * l2 * c12,
    ])
    return M, C, G


def kinematics(q, qd, l1, l2):
    """Sec. VI / Assumption (A1): forward kinematics x = h(q), Jacobian J(q) = dh/dq, and its
    exact time derivative Jdot(q, qd) (closed form)."""
    c1 = math.cos(q[0])
    s1 = math.sin(q[0])
    c12 = math.cos(q[0] + q[1])
    s12 = math.sin(q[0] + q[1])
    w1 = qd[0]
    w12 = qd[0] + qd[1]
    h = np.array([l1 * c1 + l2 * c12, l1 * s1 + l2 * s12])
    J = np.array([
        [-l1 * s1 - l2 * s12, -l2 * s12],
        [l1 * c1 + l2 * c12, l2 * c12],
    ])
    Jdot = np.array([
        [-l1 * c1 * w1 - l2 * c12 * w12, -l2 * c12 * w12],
        [-l1 * s1 * w1 - l2 * s12 * w12, -l2 * s12 * w12],
    ])
    return h, J, Jdot


def true_arm(q, qd, p):
    """True plant matrices (true masses and lengths)."""
    M, C, G = arm_matrices(q, qd, p["m1"], p["m2"], p["l1"], p["l2"], p["g"])
    h, J, Jdot = kinematics(q, qd, p["l1"], p["l2"])
    return M, C, G, h, J, Jdot


def nominal_arm(q, qd, p):
    """Nominal (controller) matrices M^, C^, G^, h^, J^, J^dot of eq. (2)."""
    M, C, G = arm_matrices(q, qd, p["m1_nom"], p["m2_nom"], p["l1_nom"], p["l2_nom"],
                           p["g_nom"])
    h, J, Jdot = kinematics(q, qd, p["l1_nom"], p["l2_nom"])
    return M, C, G, h, J, Jdot


# ---------------------------------------------------------------------------------------
# Environment (plant) and nominal constraint, Sec. II-B and Sec. VI
# ---------------------------------------------------------------------------------------

def contact_force(q, qd, p):
    """True contact (plant only, docs/paper-conventions.md): frictionless unilateral penalty spring on the TRUE
    surface x2 = (x1 - d_G) tan(delta), with TRUE kinematics.  Returns F (2,), the force the
    end-effector exerts on the surface (along the inward normal n)."""
    delta = p["delta"]
    x, J, _ = kinematics(q, qd, p["l1"], p["l2"])
    n = np.array([math.sin(delta), -math.cos(delta)])
    pen = (x[0] - p["d_G"]) * math.sin(delta) - x[1] * math.cos(delta)
    pen_dot = float(n @ (J @ qd))
    if pen > 0.0:
        fn = max(0.0, p["k_contact"] * pen + p["c_contact"] * pen_dot)
    else:
        fn = 0.0
    return fn * n


def nominal_constraint(p):
    """Assumptions (A2)-(A4), eqs. (3)-(4), (6): nominal constraint gradient A^ = [Sigma Pi],
    Gamma = -Pi^-1 Sigma, S = dx/du = [[1, 0], [Gamma, 1]], Sdot = 0 (straight surface)."""
    dh = p["delta_nom"]
    if p["scaling"] == "paper":
        Sigma = math.tan(dh)
        Pi = -1.0
    elif p["scaling"] == "unit":
        Sigma = math.sin(dh)
        Pi = -math.cos(dh)
    else:
        raise ValueError("scaling must be 'paper' or 'unit', got %r" % (p["scaling"],))
    A = np.array([[Sigma, Pi]])  # 1 x 2
    Gamma = -Sigma / Pi  # eq. (4)
    S = np.array([[1.0, 0.0], [Gamma, 1.0]])
    Sdot = np.zeros((2, 2))
    return A, Sigma, Pi, Gamma, S, Sdot


def measurements(q, qd, F, p):
    """What the controller measures: u1 = h^(q)_1, u1_dot = (J^(q) qd)_1 with NOMINAL
    kinematics, and lambda = A^ F / (A^ A^T) (least squares on F = A^T lambda)."""
    _, _, _, hh, Jh, _ = nominal_arm(q, qd, p)
    A, _, _, _, _, _ = nominal_constraint(p)
    u1 = hh[0]
    u1_dot = (Jh @ qd)[0]
    lam = float((A @ F)[0] / (A @ A.T)[0, 0])
    return u1, u1_dot, lam


# ---------------------------------------------------------------------------------------
# Reduced model, eq. (9) with the corrections of docs/paper-conventions.md, and partitions for eqs. (11)-(14)
# ---------------------------------------------------------------------------------------

def reduced_model(q, qd, p):
    """Eq. (9) (corrected): with nominal arm matrices at measured q, qd
        Mbar = S^T J^-T M^ J^-1 S
        Cbar = S^T J^-T { M^ J^-1 Sdot + [C^ - M^ J^-1 J^dot] J^-1 S }
        Gbar = S^T J^-T G^
        Bbar = S^T J^-T
    Returns the full 2x2 / 2-vector matrices."""
    Mh, Ch, Gh, _, Jh, Jhdot = nominal_arm(q, qd, p)
    _, _, _, _, S, Sdot = nominal_constraint(p)
    Jinv = np.linalg.inv(Jh)
    JinvT = Jinv.T
    Mbar = S.T @ JinvT @ Mh @ Jinv @ S
    Cbar = S.T @ JinvT @ (Mh @ Jinv @ Sdot + (Ch - Mh @ Jinv @ Jhdot) @ Jinv @ S)
    Gbar = S.T @ JinvT @ Gh
    Bbar = S.T @ JinvT
    return Mbar, Cbar, Gbar, Bbar


# ---------------------------------------------------------------------------------------
# References, disturbance, NN activations
# ---------------------------------------------------------------------------------------

def references(t):
    """Sec. VI: u1d = 1.5 + 0.2 cos(pi t), lam_d = 60 - 20 cos(pi t), analytic derivatives."""
    u1d = 1.5 + 0.2 * math.cos(math.pi * t)
    u1d_dot = -0.2 * math.pi * math.sin(math.pi * t)
    u1d_ddot = -0.2 * math.pi ** 2 * math.cos(math.pi * t)
    lam_d = 60.0 - 20.0 * math.cos(math.pi * t)
    return u1d, u1d_dot, u1d_ddot, lam_d


def disturbance(t, p):
    """Sec. VI: square wave of amplitude dist_amp, period dist_period, on both joints.
    d = +amp if floor((t - phase) / (period / 2)) is even, else -amp."""
    k = int(math.floor((t - p["dist_phase"]) / (p["dist_period"] / 2.0)))
    d = p["dist_amp"] if k % 2 == 0 else -p["dist_amp"]
    return np.array([d, d])


def centres_p(p):
    return p["centres_p_start"] + p["centres_p_step"] * np.arange(p["centres_p_count"])


def centres_f(p):
    return p["centres_f_start"] + p["centre_step_f"] * np.arange(p["centres_f_count"])


def hidden_layer(phi, centres, slope):
    """Eq. (17)-(18): xi_i = tanh(alpha (phi - c_i)); Xi = xi^T is the 1 x j row of eq. (19)."""
    return np.tanh(slope * (phi - centres))


# ---------------------------------------------------------------------------------------
# Riccati design, eq. (35) / eq. (40)
# ---------------------------------------------------------------------------------------

def error_system(p):
    """Eq. (29): A_p = [[0, 1], [-K_p, -K_v]], B_p = [0; 1] (m = 1)."""
    Ap = np.array([[0.0, 1.0], [-p["K_p"], -p["K_v"]]])
    Bp = np.array([[0.0], [1.0]])
    return Ap, Bp


def design_P(params=None, eq="35"):
    """Solve the Riccati-like equation
        eq. (35): A^T P + P A - P B (2 R_p^-1 - 1/rho^2) B^T P + Q_p = 0
        eq. (40): A^T P + P A - P B (  R_p^-1 - 1/rho^2) B^T P + Q_p = 0
    through the stable invariant subspace of the Hamiltonian
        H = [[A, -B W B^T], [-Q, -A^T]],  W = (2 or 1)/R_p - 1/rho^2,
    (ordered real Schur form, scipy.linalg.schur sort='lhp'); P = X2 X1^-1.
    Works for indefinite W (eq. (40) with the paper's numbers).  Checks residual, symmetry,
    P > 0 and that A - B W B^T P is Hurwitz."""
    p = _merge(params)
    Ap, Bp = error_system(p)
    Q = np.asarray(p["Q_p"], dtype=float)
    Rp = float(p["R_p"])
    rho = float(p["rho"])
    if eq == "35":
        W = 2.0 / Rp - 1.0 / rho ** 2
    elif eq == "40":
        W = 1.0 / Rp - 1.0 / rho ** 2
    else:
        raise ValueError("eq must be '35' or '40'")
    BWB = W * (Bp @ Bp.T)
    H = np.block([[Ap, -BWB], [-Q, -Ap.T]])
    T, Z, sdim = scipy.linalg.schur(H, output="real", sort="lhp")
    if sdim != 2:
        raise RuntimeError("Hamiltonian has %d stable eigenvalues, expected 2" % sdim)
    X1 = Z[:2, :2]
    X2 = Z[2:, :2]
    P = X2 @ np.linalg.inv(X1)
    P = 0.5 * (P + P.T)
    res = Ap.T @ P + P @ Ap - P @ BWB @ P + Q
    if np.max(np.abs(res)) > 1e-9 * max(1.0, np.max(np.abs(P))):
        raise RuntimeError("Riccati residual too large: %r" % res)
    if np.min(np.linalg.eigvalsh(P)) <= 0.0:
        raise RuntimeError("P is not positive definite: %r" % P)
    if np.max(np.linalg.eigvals(Ap - BWB @ P).real) >= 0.0:
        raise RuntimeError("A - B W B^T P is not Hurwitz")
    return P


# ---------------------------------------------------------------------------------------
# Controller: torque eq. (24)-(26) / (51) / Sec. VI FL-like law, and its ODEs
# ---------------------------------------------------------------------------------------

def controller_outputs(controller, t, y, F, p, P):
    """Torque law eq. (24) with Lambda_p (25), Lambda_f (26):
        tau = [B1; B2 - M21 M11^-1 B1]^-1 [Lambda_p; Lambda_f]
        Lambda_p = M11 [u1d_dd - K_v e_dot - K_p e + v_p - Xi_p Theta_p] + C11 u1_dot + G1
        Lambda_f = Pi^T [lam_d + z + v_lam - Xi_f Theta_f]
                   + [C21 - M21 M11^-1 C11] u1_dot + [G2 - M21 M11^-1 G1]
    "hinf_nn": v_p = -R_p^-1 B_p^T P_p x_p (33), v_lam = -(beta/2) e_lam (32), NN terms.
    "hinf":    same without NN terms, eq. (51).
    "fl":      v_p = v_lam = 0, no NN terms (Sec. VI, u1d_ddot per docs/paper-conventions.md).
    Also returns the controller/index derivatives:
        z_dot = -mu_z z - alpha_z e_lam                        (27)
        Theta_p_dot = gamma_1 Xi_p^T B_p^T P_p x_p              (30)  (hinf_nn only)
        Theta_f_dot = gamma_2 Xi_f^T e_lam                      (31)  (hinf_nn only)
        J_dot = x_p^T Q_p x_p + alpha_lam e_lam^2 + alpha_lam mu_z/(1+beta_lam) z^2   (34)
    """
    if controller not in CONTROLLERS:
        raise ValueError("controller must be one of %r" % (CONTROLLERS,))
    q = y[IDX_Q]
    qd = y[IDX_QD]
    z = y[IDX_Z]
    theta_p = y[IDX_THP]
    theta_f = y[IDX_THF]

    # measurements (nominal kinematics / nominal constraint)
    u1, u1_dot, lam = measurements(q, qd, F, p)
    _, _, Pi, _, _, _ = nominal_constraint(p)

    # references and errors
    u1d, u1d_dot, u1d_ddot, lam_d = references(t)
    e_u1 = u1 - u1d
    e_u1_dot = u1_dot - u1d_dot
    e_lam = lam - lam_d
    x_p = np.array([e_u1, e_u1_dot])

    # reduced model (9) and its partitions (m = k = 1)
    Mbar, Cbar, Gbar, Bbar = reduced_model(q, qd, p)
    M11 = Mbar[0, 0]
    M21 = Mbar[1, 0]
    C11 = Cbar[0, 0]
    C21 = Cbar[1, 0]
    G1 = Gbar[0]
    G2 = Gbar[1]
    B1 = Bbar[0, :]
    B2 = Bbar[1, :]

    Ap, Bp = error_system(p)
    Kp = p["K_p"]
    Kv = p["K_v"]

    # robustifying terms (32)-(33)
    if controller == "fl":
        v_p = 0.0
        v_lam = 0.0
    else:
        v_p = float(-(1.0 / p["R_p"]) * (Bp.T @ P @ x_p)[0])
        v_lam = -(p["beta_lam"] / 2.0) * e_lam

    # neural networks (17)-(19)
    xi_p = hidden_layer(e_u1 + e_u1_dot, centres_p(p), p["slope"])
    xi_f = hidden_layer(e_lam + z, centres_f(p), p["slope"])
    if controller == "hinf_nn":
        nn_p = float(xi_p @ theta_p)
        nn_f = float(xi_f @ theta_f)
    else:
        nn_p = 0.0
        nn_f = 0.0

    Lambda_p = M11 * (u1d_ddot - Kv * e_u1_dot - Kp * e_u1 + v_p - nn_p) + C11 * u1_dot + G1
    Lambda_f = (Pi * (lam_d + z + v_lam - nn_f)
                + (C21 - M21 / M11 * C11) * u1_dot
                + (G2 - M21 / M11 * G1))
    Bmat = np.vstack([B1, B2 - M21 / M11 * B1])
    tau = np.linalg.inv(Bmat) @ np.array([Lambda_p, Lambda_f])

    # controller ODEs
    z_dot = -p["mu_z"] * z - p["alpha_z"] * e_lam
    if controller == "hinf_nn":
        BtPx = float((Bp.T @ P @ x_p)[0])
        theta_p_dot = p["gamma_1"] * xi_p * BtPx
        theta_f_dot = p["gamma_2"] * xi_f * e_lam
    else:
        theta_p_dot = np.zeros(N_P)
        theta_f_dot = np.zeros(N_F)

    Q = np.asarray(p["Q_p"], dtype=float)
    J_dot = (float(x_p @ Q @ x_p) + p["alpha_lam"] * e_lam ** 2
             + p["alpha_lam"] * p["mu_z"] / (1.0 + p["beta_lam"]) * z ** 2)

    return {
        "tau": tau, "z_dot": z_dot, "theta_p_dot": theta_p_dot,
        "theta_f_dot": theta_f_dot, "J_dot": J_dot,
        "u1": u1, "u1_dot": u1_dot, "lam": lam,
    }


# ---------------------------------------------------------------------------------------
# Plant, eq. (1)
# ---------------------------------------------------------------------------------------

def plant_acceleration(q, qd, tau, w, F, p):
    """Eq. (1) with true parameters: M qdd + C qd + G + J^T F = tau + w  ->  qdd."""
    M, C, G, _, J, _ = true_arm(q, qd, p)
    return np.linalg.solve(M, tau + w - C @ qd - G - J.T @ F)


def rhs(controller, t, y, d, p, P):
    """Closed-loop right-hand side dy/dt at time t, state y, disturbance w = d (held)."""
    q = y[IDX_Q]
    qd = y[IDX_QD]
    F = contact_force(q, qd, p)
    out = controller_outputs(controller, t, y, F, p, P)
    qdd = plant_acceleration(q, qd, out["tau"], d, F, p)
    dy = np.zeros(N_STATE)
    dy[IDX_Q] = qd
    dy[IDX_QD] = qdd
    dy[IDX_Z] = out["z_dot"]
    dy[IDX_THP] = out["theta_p_dot"]
    dy[IDX_THF] = out["theta_f_dot"]
    dy[IDX_J] = out["J_dot"]
    return dy


# ---------------------------------------------------------------------------------------
# Initial state and RK4 loop
# ---------------------------------------------------------------------------------------

def initial_q(params=None):
    """Sec. VI initial condition (docs/paper-conventions.md): TRUE arm end-effector at
    x = (u1_0, (u1_0 - d_G) tan delta) on the TRUE surface, elbow up (q2 < 0)."""
    p = _merge(params)
    l1 = p["l1"]
    l2 = p["l2"]
    x1 = p["u1_0"]
    x2 = (p["u1_0"] - p["d_G"]) * math.tan(p["delta"])
    q2 = -math.acos((x1 ** 2 + x2 ** 2 - l1 ** 2 - l2 ** 2) / (2.0 * l1 * l2))
    q1 = math.atan2(x2, x1) - math.atan2(l2 * math.sin(q2), l1 + l2 * math.cos(q2))
    return np.array([q1, q2])


def initial_state(params=None):
    y0 = np.zeros(N_STATE)
    y0[IDX_Q] = initial_q(params)
    return y0


def simulate(controller, params=PAPER, t_final=0.2, dt=1e-4):
    """Classic fixed-step RK4 on the whole state; controller re-evaluated at every stage;
    disturbance held at its value at t_k + dt/2 during step k; references at stage times."""
    p = _merge(params)
    if controller not in CONTROLLERS:
        raise ValueError("controller must be one of %r" % (CONTROLLERS,))
    P = None if controller == "fl" else design_P(p, eq="35")
    n_steps = int(round(t_final / dt))

    t_out = np.zeros(n_steps + 1)
    y_out = np.zeros((n_steps + 1, N_STATE))
    tau_out = np.zeros((n_steps + 1, 2))
    lam_out = np.zeros(n_steps + 1)
    u1_out = np.zeros(n_steps + 1)
    u1d_out = np.zeros(n_steps + 1)

    y = initial_state(p)
    for k in range(n_steps + 1):
        t = k * dt
        t_out[k] = t
        y_out[k] = y
        F = contact_force(y[IDX_Q], y[IDX_QD], p)
        out = controller_outputs(controller, t, y, F, p, P)
        tau_out[k] = out["tau"]
        lam_out[k] = out["lam"]
        u1_out[k] = out["u1"]
        u1d_out[k] = out["u1_dot"]
        if k == n_steps:
            break
        d = disturbance(t + 0.5 * dt, p)
        k1 = rhs(controller, t, y, d, p, P)
        k2 = rhs(controller, t + 0.5 * dt, y + 0.5 * dt * k1, d, p, P)
        k3 = rhs(controller, t + 0.5 * dt, y + 0.5 * dt * k2, d, p, P)
        k4 = rhs(controller, t + dt, y + dt * k3, d, p, P)
        y = y + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

    return {"t": t_out, "y": y_out, "tau": tau_out, "lam": lam_out,
            "u1": u1_out, "u1_dot": u1d_out}


# ---------------------------------------------------------------------------------------
# Self-check
# ---------------------------------------------------------------------------------------

def _check_reduced_identity(scaling, rng, n_trials=20):
    """Reduced-model identity of eq. (9) on an exact model (nominal = true params):
    forward dynamics with F = A^T lambda, u = [x1, x2 - Omega(x1)], u_ddot from
    x_ddot = J qdd + Jdot qd, then check Mbar u_dd + Cbar u_d + Gbar + S^T A^T lam = Bbar tau."""
    p = dict(PAPER)
    p["scaling"] = scaling
    p["m1_nom"], p["m2_nom"] = p["m1"], p["m2"]
    p["l1_nom"], p["l2_nom"] = p["l1"], p["l2"]
    p["delta_nom"], p["d_G_nom"], p["g_nom"] = p["delta"], p["d_G"], p["g"]
    A, _, _, Gamma, S, _ = nominal_constraint(p)
    worst = 0.0
    for _ in range(n_trials):
        q = np.array([rng.uniform(-1.5, 1.5), rng.uniform(-2.5, -0.3)])
        qd = rng.normal(size=2)
        tau = 10.0 * rng.normal(size=2)
        lam = 50.0 * rng.normal()
        F = A.T[:, 0] * lam
        M, C, G, x, J, Jdot = true_arm(q, qd, p)
        qdd = np.linalg.solve(M, tau - C @ qd - G - J.T @ F)
        xd = J @ qd
        xdd = J @ qdd + Jdot @ qd
        # u = [x1, x2 - Omega(x1)], Omega(x1) = (x1 - d_G) * Gamma  (straight line)
        ud = np.array([xd[0], xd[1] - Gamma * xd[0]])
        udd = np.array([xdd[0], xdd[1] - Gamma * xdd[0]])
        Mbar, Cbar, Gbar, Bbar = reduced_model(q, qd, p)
        lhs = Mbar @ udd + Cbar @ ud + Gbar + (S.T @ A.T)[:, 0] * lam
        rhs_ = Bbar @ tau
        err = np.max(np.abs(lhs - rhs_)) / max(1.0, np.max(np.abs(rhs_)))
        worst = max(worst, err)
        # S^T A^T = [0; Pi]
        assert abs((S.T @ A.T)[0, 0]) < 1e-12
    return worst


def _self_check():
    np.set_printoptions(precision=6, suppress=False)
    rng = np.random.default_rng(12345)

    # 1. P_p of eq. (35)
    P = design_P(PAPER, eq="35")
    P_exp = np.array([[1.30300, 0.02775], [0.02775, 0.05840]])
    print("P_p (35) =\n", P)
    assert np.allclose(P, P_exp, atol=5e-5), P
    Ap, Bp = error_system(PAPER)
    R_eff = 1.0 / (2.0 / PAPER["R_p"] - 1.0 / PAPER["rho"] ** 2)
    P_care = scipy.linalg.solve_continuous_are(Ap, Bp, PAPER["Q_p"], np.array([[R_eff]]))
    assert np.allclose(P, P_care, rtol=1e-10, atol=1e-12)
    closed = Ap - Bp @ Bp.T @ P / PAPER["R_p"]
    assert np.max(np.linalg.eigvals(closed).real) < 0.0
    P40 = design_P(PAPER, eq="40")
    print("P_p (40) =\n", P40)

    # 2. initial state
    q0 = initial_q(PAPER)
    print("q0 =", q0)
    assert abs(q0[0] - math.pi / 4) < 1e-4 and abs(q0[1] + 0.60127) < 1e-4, q0
    _, _, _, hh, _, _ = nominal_arm(q0, np.zeros(2), PAPER)
    print("nominal h(q0) =", hh)
    F0 = contact_force(q0, np.zeros(2), PAPER)
    assert np.max(np.abs(F0)) < 1e-6, F0

    # 3. Mdot - 2C skew-symmetric (finite-difference Mdot), true and nominal params
    eps = 1e-6
    for (m1, m2, l1, l2) in [(PAPER["m1"], PAPER["m2"], PAPER["l1"], PAPER["l2"]),
                             (PAPER["m1_nom"], PAPER["m2_nom"], PAPER["l1_nom"],
                              PAPER["l2_nom"])]:
        for _ in range(20):
            q = rng.uniform(-3, 3, size=2)
            qd = rng.normal(size=2)
            Mp, _, _ = arm_matrices(q + eps * qd, qd, m1, m2, l1, l2, 9.8)
            Mm, _, _ = arm_matrices(q - eps * qd, qd, m1, m2, l1, l2, 9.8)
            _, C, _ = arm_matrices(q, qd, m1, m2, l1, l2, 9.8)
            Nmat = (Mp - Mm) / (2 * eps) - 2.0 * C
            assert np.max(np.abs(Nmat + Nmat.T)) < 1e-7, Nmat
    print("Mdot - 2C skew-symmetric: ok")

    # 3b. Jdot closed form vs finite difference
    for _ in range(20):
        q = rng.uniform(-3, 3, size=2)
        qd = rng.normal(size=2)
        _, Jp, _ = kinematics(q + eps * qd, qd, 1.1, 0.9)
        _, Jm, _ = kinematics(q - eps * qd, qd, 1.1, 0.9)
        _, _, Jdot = kinematics(q, qd, 1.1, 0.9)
        assert np.max(np.abs((Jp - Jm) / (2 * eps) - Jdot)) < 1e-7
    print("Jdot closed form: ok")

    # 4. reduced-model identity, both scalings
    for scaling in ("paper", "unit"):
        worst = _check_reduced_identity(scaling, rng)
        print("reduced-model identity (%s scaling): max rel err %.2e" % (scaling, worst))
        assert worst < 1e-10

    # 5. closed-loop runs
    for ctrl in CONTROLLERS:
        t0 = time.perf_counter()
        res = simulate(ctrl, PAPER, t_final=0.2, dt=1e-4)
        wall = time.perf_counter() - t0
        n = len(res["t"]) - 1
        y = res["y"]
        assert np.all(np.isfinite(y)) and np.all(np.isfinite(res["tau"]))
        yf = y[-1]
        print("[%s] %d steps, %.3f s total, %.1f us/step" % (ctrl, n, wall, 1e6 * wall / n))
        print("   q(0.2) = %r" % (yf[IDX_Q].tolist(),))
        print("   qd(0.2) = %r" % (yf[IDX_QD].tolist(),))
        print("   z(0.2) = %.10g" % yf[IDX_Z])
        print("   |theta_p| = %.10g, |theta_f| = %.10g"
              % (np.linalg.norm(yf[IDX_THP]), np.linalg.norm(yf[IDX_THF])))
        print("   J(0.2) = %.10g" % yf[IDX_J])
        print("   u1 = %.10g, lam = %.10g, tau = %r"
              % (res["u1"][-1], res["lam"][-1], res["tau"][-1].tolist()))
    # the printed centre step
    res = simulate("hinf_nn", {"centre_step_f": 0.05}, t_final=0.2, dt=1e-4)
    assert np.all(np.isfinite(res["y"]))
    yf = res["y"][-1]
    print("[hinf_nn, centre_step_f=0.05] q=%r z=%.10g |thp|=%.10g |thf|=%.10g J=%.10g"
          % (yf[IDX_Q].tolist(), yf[IDX_Z], np.linalg.norm(yf[IDX_THP]),
             np.linalg.norm(yf[IDX_THF]), yf[IDX_J]))
    print("self-check passed")


if __name__ == "__main__":
    _self_check()
