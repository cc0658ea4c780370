"""Derivation of robot deleva55's description from de Leva (1996), Table 4, female values.

de Leva P. (1996) Adjustments to Zatsiorsky-Seluyanov's segment inertia parameters.
J. Biomechanics 29(9), 1223-1230, Table 4 (female columns). Values as recalled by the author of the
outsider trial (no copy of the paper at hand); the ones marked UNSURE are not certain.
Plain arithmetic, no project code.
"""
M = 55.0           # body mass [kg] (brief)
H = 1.60           # stature [m] (brief)
H_SRC = 1.735      # de Leva's female mean stature [m]
s = H / H_SRC      # length scale
# (mass % of body, length mm, CoM % from proximal endpoint, sagittal radius of gyration % of length)
tab = {
    "head":     (6.68, 243.7, 58.94, 33.0),   # VERT-CERV; length and r_sag UNSURE
    "trunk":    (42.57, 529.3, 41.51, 35.7),  # CERV-MIDH, CoM from CERV; r_sag UNSURE
    "upperarm": (2.55, 275.1, 57.54, 27.8),
    "forearm":  (1.38, 264.3, 45.59, 26.1),
    "hand":     (0.56, 78.0, 74.74, 53.1),
    "thigh":    (14.78, 368.5, 36.12, 36.9),  # HJC-KJC
    "shank":    (4.81, 432.3, 44.16, 27.1),   # KJC-LMAL
    "foot":     (1.29, 228.3, 40.14, 29.9),   # HEEL-TTIP
}
total = tab["head"][0] + tab["trunk"][0] + 2 * sum(tab[k][0] for k in ("upperarm", "forearm", "hand", "thigh", "shank", "foot"))
print(f"mass fractions sum {total:.2f} %")
m = {k: v[0] / 100 * M for k, v in tab.items()}
L = {k: v[1] / 1000 * s for k, v in tab.items()}
c = {k: v[2] / 100 * L[k] for k, v in tab.items()}
I = {k: m[k] * (v[3] / 100 * L[k]) ** 2 for k, v in tab.items()}
ANKLE_H = 0.06     # ASSUMPTION: lateral malleolus height above the floor [m] (not in de Leva's Table 4)
SJC_BELOW_CERV = 0.05  # ASSUMPTION: shoulder joint centre below cervicale [m]
# torso = HAT: heights above the hip (MIDH)
cerv = L["trunk"]
torso_len = H - ANKLE_H - L["thigh"] - L["shank"]        # hip to vertex
parts = [  # (mass, CoM height above hip, own inertia)
    (m["trunk"], cerv - c["trunk"], I["trunk"]),
    (m["head"], torso_len - c["head"], I["head"]),
]
sjc = cerv - SJC_BELOW_CERV
for _ in range(2):
    parts.append((m["upperarm"], sjc - c["upperarm"], I["upperarm"]))
    parts.append((m["forearm"], sjc - L["upperarm"] - c["forearm"], I["forearm"]))
    parts.append((m["hand"], sjc - L["upperarm"] - L["forearm"] - c["hand"], I["hand"]))
mt = sum(p[0] for p in parts)
zt = sum(p[0] * p[1] for p in parts) / mt
It = sum(p[2] + p[0] * (p[1] - zt) ** 2 for p in parts)
out = {
    "torso.length": torso_len, "torso.mass": mt, "torso.com_from_proximal": zt, "torso.inertia": It,
    "thigh.length": L["thigh"], "thigh.mass": m["thigh"], "thigh.com_from_proximal": c["thigh"], "thigh.inertia": I["thigh"],
    "shin.length": L["shank"], "shin.mass": m["shank"], "shin.com_from_proximal": c["shank"], "shin.inertia": I["shank"],
    "foot.length": L["foot"], "foot.mass": m["foot"], "foot.inertia": I["foot"],
}
for k, v in out.items():
    print(f"{k}={v:.6g}")
print("total mass", mt + 2 * (m["thigh"] + m["shank"] + m["foot"]))
print("parts (m, z, I):", [(round(a, 4), round(b, 4), round(cc, 5)) for a, b, cc in parts])
