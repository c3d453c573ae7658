"""The thesis' numbers the imitation configs must equal, transcribed from ../shared/THESIS.md (the
section of each is named); ``test_thesis_values.py`` checks this transcription against THESIS.md
itself when the file is there."""

from __future__ import annotations

# Table 5.2 (THESIS.md 3.3): term -> (weight, scale)
TABLE_5_2 = {"pose": (0.65, 2.0), "velocity": (0.1, 0.1), "end_effector": (0.15, 40.0), "root": (0.1, 10.0)}

# Tables 6.4 and 6.5 (THESIS.md 4.5, 4.6): column -> (k_p,b, k_p,h, k_v,b, k_v,h); k_e 40, k_r 10.
TABLE_6_4 = {"default": (2, 2, 0.1, 0.1), "run1": (2, 0.5, 0.1, 5e-4), "run2": (2, 0.2, 0.1, 1e-4),
             "run3": (2, 0.2, 5e-3, 1e-4)}
TABLE_6_5 = {"run1": (2, 2, 5e-3, 1e-4), "run2": (2, 0.2, 0.1, 5e-4), "run3": (1, 0.2, 1e-3, 1e-4),
             "run4": (0.5, 0.2, 5e-3, 1e-4)}
K_END_EFFECTOR, K_ROOT, K_ROOT_CODE = 40.0, 10.0, 5.0

# Table D.1, best row (THESIS.md 3.5, 8), SB3 names.
TABLE_D1_BEST = {"batch_size": 128, "gamma": 0.9, "learning_rate": 1e-5, "log_std_init": -2, "n_epochs": 10,
                 "n_steps": 1024, "ortho_init": False, "weight_decay": 1e-5}

# Tables 6.3 and 6.6 (THESIS.md 4.4, 4.7).
TABLE_6_3 = {"hidden": [256, 512, 256], "learning_rate": 3e-6, "n_steps": 1024, "batch_size": 128,
             "log_std": -3, "gamma": 0.95, "n_epochs": 10}
TABLE_6_6 = {**TABLE_6_3, "n_steps": 512, "n_epochs": 5}

# Search spaces: Table 5.3 (3.4), Table 6.2 (4.3), the k grid of section 6.3.2 (4.1).
TABLE_5_3 = {"learning_rate": [1e-6, 3e-6, 1e-5, 3e-5], "n_steps": [512, 1024, 4096],
             "weight_decay": [1e-5, 1e-4], "batch_size": [128, 256, 512], "ortho_init": [True, False],
             "gamma": [0.9, 0.95], "log_std_init": [-3, -2, -1], "n_epochs": [3, 5, 10]}
TABLE_6_2 = {"learning_rate": [1e-6, 3e-6, 1e-5, 3e-5, 1e-4], "n_steps": [512, 1024, 4096],
             "batch_size": [128, 256, 512], "log_std": [-5, -3, -2, -1], "gamma": [0.9, 0.95],
             "n_epochs": [3, 5, 10]}
K_GRID = {"k_p,h": [2, 1, 0.5, 0.2], "k_v,h": [1e-1, 1e-2, 1e-3, 1e-4]}

# The authors' code (THESIS.md 10.1): 10 environments per update (train_ppo.py); the hand script's
# count is not recorded in THESIS.md, so the hand uses the same 10.
AUTHORS_ENVS_UPPER_BODY, AUTHORS_ENVS_HAND = 10, 10
# Upper-body stable-PD gains of the authors' code (10.1): group -> (kp, kd).
UPPER_BODY_GAINS = {"chest": (1000, 100), "neck": (100, 10), "shoulder": (400, 8), "elbow": (300, 6),
                    "wrist": (50, 0.5), "fingers": (50, 0.5)}
# The text's upper-body controller (4.1, 4.9): DeepMimic's body gains, shoulder k_d 8 and elbow k_d 6
# (as the code's above), and the chapter-5 hand's position-control gains for the hands (3.1): kp, kd.
UPPER_BODY_ARM_KD_TEXT = {"shoulder": 8, "elbow": 6}
HAND_GAINS_TEXT = (0.22, 0.87)
