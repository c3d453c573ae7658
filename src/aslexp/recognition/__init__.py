"""Recognition of phonological properties of signs from keypoint sequences.

    models      build_classifier(name, params, ...) and the classifiers (baselines, logreg,
                svm, mlp, lstm, gru, stgcn, cnn3d)
    train       TrainerConfig, fit (early stopping on val MCC), fit_final, checkpoints
    metrics     classification_metrics, Fleiss' kappa, mutual misclassification
    experiment  run_recognition: seeds x (validate, retrain, test) -> metrics dict + run files
    report      collect_table: the thesis' models x properties table
"""
