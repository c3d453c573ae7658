"""Recognition of phonological properties of signs from keypoint sequences.

    registry    register_classifier: a classifier is a builder, its parameters and a YAML
    models      build_classifier(name, params, ...) and the built-in classifiers (chance baselines,
                logreg, svm, the rf/hgb feature baseline, mlp, lstm, gru, stgcn, slgcn, cnn3d)
    train       TrainerConfig, fit (validation, early stopping or a fixed budget), fit_final,
                checkpoints; device and precision (device.py), augmentation (augment.py)
    metrics     classification_metrics, intervals over splits, paired comparisons, Fleiss' kappa,
                the thesis' mutual misclassification
    experiment  run_recognition: K splits x seeds x (validate, retrain, test) -> metrics + run files
    report      the platform's table with intervals, comparisons, and the thesis' table layouts

Importable without Hydra, OmegaConf, Optuna, a physics engine, gymnasium, torchrl, matplotlib or tqdm
(plots are skipped with a warning where matplotlib is missing): a bare GPU node runs it.
"""
