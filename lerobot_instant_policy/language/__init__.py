"""Tasks said in words (paper §4.3 and appendix, modality transfer): a small graph network, the language head, that
predicts Instant Policy's bottleneck (φ's output at the current gripper nodes) from the current observation and a
sentence, so that the frozen ψ acts on a task said in words instead of demonstrations.

``text_encoder`` (sentences → unit vectors, offline), ``paraphrases`` (the sentences of every task of the suites,
some held out), ``language_head`` (the head and what it reads of the trained network), ``context`` (a control step's
context from words) and ``task_language`` (the policy's language path: task strings → sentences → contexts,
``--policy.context=language``). The head's regression targets and its training live in the training room
(:mod:`..training.language_targets`, :mod:`..training.language_head_training`); its command line is
``cli/train_language.py``. The room depends on the model layer and the ground floor only; the policy imports ``task_language`` and its
config ``paraphrases`` (to check ``language_paraphrase``).
"""
