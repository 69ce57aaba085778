"""Load every serial chain of a folder of URDF files with hinfnn and with Pinocchio, and compare.

Usage: python tests/urdf_corpus.py FOLDER [--states 3] [--json OUT]

For each ``.urdf`` file below FOLDER: Pinocchio's ``buildModelFromXML`` (whole file, fixed base)
says whether Pinocchio loads it; then every chain a user could pick is tried with
:func:`hinfnn.model.urdf.load_urdf`: from the root link (or the child of the last floating/planar
joint above) to each leaf link, one chain per distinct set of moving joints. A chain that loads is
compared with Pinocchio's model of the same file reduced to that chain (every other joint locked
at its neutral position, as hinfnn merges side branches with their joints at zero): M(q),
C(q, q̇)q̇ + G(q) and the end-effector's frame Jacobian (base frame) on a few seeded random states,
as max |hinfnn − Pinocchio| / max(1, max |Pinocchio|).

Prints one line per file (chains tried, loaded, refused with the reasons) and a summary. Not a
test: it needs a corpus on disk (e.g. ``git show`` of Gepetto/example-robot-data and
RobotLocomotion/models); ``tests/test_user_arms.py`` checks the shipped ones.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import warnings
import xml.etree.ElementTree as ET

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import pinocchio as pin  # noqa: E402

from hinfnn.model.urdf import MOVING_TYPES, UrdfError, UrdfWarning, load_urdf  # noqa: E402


def tree(path):
    """(root links, children {link: [(joint name, type, child, mimic)]}, parent {link: (joint, type, parent)})."""
    root = ET.parse(path).getroot()
    links = [el.get("name") for el in root.findall("link")]
    children = collections.defaultdict(list)
    parent = {}
    for j in root.findall("joint"):
        p, c = j.find("parent").get("link"), j.find("child").get("link")
        children[p].append((j.get("name"), j.get("type"), c, j.find("mimic") is not None))
        parent[c] = (j.get("name"), j.get("type"), p, j.find("mimic") is not None)
    roots = [name for name in links if name not in parent]
    return roots, children, parent, links


def chains(path):
    """(base, ee, moving joints) for every leaf, one per distinct set of moving joints."""
    roots, children, parent, links = tree(path)
    out, seen = [], set()
    leaves = [name for name in links if not children.get(name)]
    for leaf in leaves:
        up, link = [], leaf
        while link in parent:
            up.append(parent[link] + (link,))
            link = parent[link][2]
        up.reverse()  # joints root -> leaf: (joint, type, parent, mimic, child)
        base = link
        for j in up:
            if j[1] in ("floating", "planar"):
                base = j[4]
        below = up[[j[4] for j in up].index(base) + 1:] if base != link else up
        moving = tuple(j[0] for j in below if j[1] in MOVING_TYPES)
        if not moving or moving in seen:
            continue
        seen.add(moving)
        out.append((base, leaf, moving))
    return out


def compare(path, text, base, ee, moving, chain, states, rng):
    """Worst relative difference of M, C q̇ + G and the frame Jacobian on ``states`` random states:
    Pinocchio's whole model with every other joint at its neutral position and at rest, restricted
    to the chain's joints (what hinfnn's merging of side branches at zero means)."""
    model = pin.buildModelFromXML(text)
    data = model.createData()
    joints = [model.joints[model.getJointId(name)] for name in chain.joint_names]
    if any(jm.nv != 1 for jm in joints):
        return None, "a chain joint with nv != 1 in Pinocchio"
    iq = [jm.idx_q for jm in joints]
    iv = [jm.idx_v for jm in joints]
    nq2 = [jm.nq == 2 for jm in joints]
    fb, fe = model.getFrameId(base, pin.FrameType.BODY), model.getFrameId(ee, pin.FrameType.BODY)
    worst = 0.0
    for _ in range(states):
        q = rng.uniform(-1.5, 1.5, chain.n)
        qd = rng.normal(size=chain.n)
        qp, vp = pin.neutral(model), np.zeros(model.nv)
        for k in range(chain.n):
            if nq2[k]:
                qp[iq[k]:iq[k] + 2] = (np.cos(q[k]), np.sin(q[k]))
            else:
                qp[iq[k]] = q[k]
            vp[iv[k]] = qd[k]
        pin.framesForwardKinematics(model, data, qp)
        Rb = data.oMf[fb].rotation.copy()
        M = np.asarray(pin.crba(model, data, qp))
        M = (np.triu(M) + np.triu(M, 1).T)[np.ix_(iv, iv)]
        b = np.asarray(pin.nonLinearEffects(model, data, qp, vp))[iv]
        pin.computeJointJacobians(model, data, qp)
        pin.updateFramePlacements(model, data)
        J = np.asarray(pin.getFrameJacobian(model, data, fe, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED))[:, iv]
        J = np.vstack([Rb.T @ J[:3], Rb.T @ J[3:]])  # world-aligned axes -> the chain's base axes
        ch = chain.with_gravity(Rb.T @ model.gravity.linear)
        got = {"M": np.asarray(ch.M(q)), "bias": np.asarray(ch.bias(q, qd)),
               "J": np.asarray(ch.frame_jacobian(q))}
        for k, ref in (("M", M), ("bias", b), ("J", J)):
            worst = max(worst, float(np.max(np.abs(got[k] - ref)) / max(1.0, np.max(np.abs(ref)))))
    return worst, None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("folder")
    ap.add_argument("--states", type=int, default=3)
    ap.add_argument("--json")
    args = ap.parse_args()
    files = sorted(os.path.join(d, f) for d, _, fs in os.walk(args.folder) for f in fs if f.endswith(".urdf"))
    rng = np.random.default_rng(0)
    report = []
    totals = collections.Counter()
    for path in files:
        rel = os.path.relpath(path, args.folder)
        text = open(path, encoding="utf-8").read()
        try:
            pin.buildModelFromXML(text)
            pin_ok, pin_err = True, None
        except Exception as err:  # noqa: BLE001 - recorded
            pin_ok, pin_err = False, str(err).splitlines()[0][:200]
        try:
            found = chains(path)
        except Exception as err:  # noqa: BLE001
            found, pin_err = [], f"tree: {err}"
        entry = {"file": rel, "pinocchio": pin_ok, "pinocchio_error": pin_err, "chains": []}
        for base, ee, moving in found:
            row = {"base": base, "ee": ee, "n": len(moving)}
            try:
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always", UrdfWarning)
                    chain = load_urdf(path, base, ee)
                notes = [str(w.message).split(": ", 2)[-1][:120] for w in caught if issubclass(w.category, UrdfWarning)]
                if notes:
                    row["warnings"] = notes
            except UrdfError as err:
                row["refused"] = f"{err.element}: {err.problem}" if err.element else err.problem
            else:
                row["loaded"] = True
                if pin_ok:
                    try:
                        row["max_rel_diff"], row["compare_error"] = compare(path, text, base, ee, moving, chain,
                                                                            args.states, rng)
                    except Exception as err:  # noqa: BLE001
                        row["compare_error"] = f"{type(err).__name__}: {err}"[:200]
            entry["chains"].append(row)
        n_ok = sum(1 for c in entry["chains"] if c.get("loaded"))
        n_ref = len(entry["chains"]) - n_ok
        totals["files"] += 1
        totals["pinocchio_loads"] += pin_ok
        totals["chains"] += len(entry["chains"])
        totals["loaded"] += n_ok
        totals["refused"] += n_ref
        totals["files_all_loaded"] += bool(entry["chains"]) and n_ref == 0
        totals["files_some_refused"] += n_ref > 0
        totals["loaded_with_warning"] += sum(1 for c in entry["chains"] if c.get("loaded") and c.get("warnings"))
        diffs = [c["max_rel_diff"] for c in entry["chains"] if c.get("max_rel_diff") is not None]
        worst = max(diffs) if diffs else None
        if worst is not None:
            totals["compared"] += len(diffs)
            totals["over_1e-12"] += sum(d > 1e-12 for d in diffs)
        reasons = collections.Counter(c["refused"].split(" (")[0] for c in entry["chains"] if "refused" in c)
        print(f"{rel}: pinocchio {'loads' if pin_ok else 'fails (' + str(pin_err) + ')'}; chains {len(entry['chains'])}, "
              f"loaded {n_ok}, refused {n_ref}" + (f", worst diff {worst:.2e}" if worst is not None else "")
              + "".join(f"\n    refused x{k}: {r}" for r, k in reasons.items())
              + "".join(f"\n    compare: {c['compare_error']}" for c in entry["chains"] if c.get("compare_error"))
              + "".join(f"\n    warning x{k}: {w}" for w, k in collections.Counter(
                  w.split(" (")[0] for c in entry["chains"] for w in c.get("warnings", ())).items()))
        report.append(entry)
    print("\nsummary:", dict(totals))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump({"totals": dict(totals), "files": report}, fh, indent=1)


if __name__ == "__main__":
    main()
