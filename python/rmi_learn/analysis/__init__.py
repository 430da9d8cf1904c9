"""Analysis: the physical analysis of a run grid (:mod:`.physical`, ``rmi analyze``) and the
report of a pipeline directory beside the paper's numbers (:mod:`.report`, ``rmi report``)."""
