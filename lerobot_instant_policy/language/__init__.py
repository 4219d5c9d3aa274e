"""Tasks said in words (paper §4.3 and appendix, modality transfer): a small graph network, the language head, that
predicts Instant Policy's bottleneck (φ's output at the current gripper nodes) from the current observation and a
sentence, so that the frozen ψ acts on a task said in words instead of demonstrations.

``text_encoder`` (sentences → unit vectors, offline), ``paraphrases`` (the sentences of every task of the suites,
some held out), ``language_head`` (the head and what it reads of the trained network), ``targets`` (the bottleneck
of demonstration frames with demonstrations of their task in context, the head's regression targets), ``training``
(the loss, the training loop and the evaluation), ``context`` (a control step's context from words) and
``task_language`` (the policy's language path: task strings → sentences → contexts, ``--policy.context=language``);
its command line is ``cli/train_language.py``. The room depends on the model, data and policy layers; the policy
imports ``task_language`` and its config ``paraphrases`` (to check ``language_paraphrase``).
"""
