"""The results page, ``docs/results.md``: one section per entry of the catalogue ``conf/results.yaml``,
rendered from snapshots (``docs/results/<id>.json``) made from run folders (``aslexp report --results``).

    catalogue    the entries, read and checked; what a command sweeps against what its runs carried
    provenance   an entry's run folders, and where and when they ran
    snapshots    made from the run folders by the entry's report kind, kept when the folders are gone
    render       the page from the catalogue and the snapshots alone
    kinds        the registry of report kinds: a new job's results are one module and one entry
    imitation, recognition, retrieval, seen_glosses, signing   the built-in kinds
    differences  how an imitation result's runs differ from the thesis' setting, from their configs
"""
