"""The public API of ``rfmitsuba``: the names the README's example uses, imported on first use."""


def test_the_public_names_are_the_functions_they_stand_for():
    import rfmitsuba
    from rfmitsuba.data.store import open_dataset
    from rfmitsuba.eval.predict import predict_run
    from rfmitsuba.eval.run import evaluate_run
    from rfmitsuba.sim.generate import GenerateConfig, generate
    from rfmitsuba.train.config import TrainConfig

    from rfmitsuba import GenerateConfig as G, TrainConfig as T, evaluate, generate as gen, open_dataset as od, \
        predict

    assert (gen, evaluate, predict, od, G, T) == (generate, evaluate_run, predict_run, open_dataset,
                                                  GenerateConfig, TrainConfig)
    assert {"generate", "train", "evaluate", "predict", "open_dataset"} <= set(rfmitsuba.__all__) & set(dir(rfmitsuba))


def test_rfmitsuba_train_trains(monkeypatch):
    """``rfmitsuba.train`` is the training package, and calling it calls
    :func:`rfmitsuba.train.trainer.train` with the same arguments, whichever was imported first."""
    import rfmitsuba
    import rfmitsuba.train.config  # noqa: F401  (the package attribute is the module from here on)
    from rfmitsuba.train import trainer

    calls = []
    monkeypatch.setattr(trainer, "train", lambda *a, **k: calls.append((a, k)) or "summary")
    from rfmitsuba import train

    assert train is rfmitsuba.train and train("ds", "run", cfg=None, quiet=True) == "summary"
    assert calls == [(("ds", "run"), {"cfg": None, "quiet": True})]


def test_an_unknown_name_is_an_attribute_error():
    import pytest

    import rfmitsuba

    with pytest.raises(AttributeError, match="no attribute 'trian'"):
        rfmitsuba.trian  # noqa: B018
