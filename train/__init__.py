"""Fine-tuning a vision-language model on the factory's two tasks (`python -m train`).

Modules: `config` (the run's settings), `tiny` (the local tiny Qwen2-VL when no model is given),
`processor` (processor loading and saving, also without torchvision), `data` (the example stream
and answer-only labels), `model` (base, LoRA, merge), `checkpoint` (atomic checkpoints), `loop`
(the training loop), `report` (loss plot and summary), `evaluate` (before/after scores) and
`feedback` (correction examples from wrong pose answers, `python -m train.feedback`).
"""

import factory._startup  # noqa: F401  (first: Ctrl-C while a command starts is one line)
