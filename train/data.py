"""Training examples from dataset folders: a lazily read, deterministically shuffled stream of
tokenized (row, task) examples whose labels are the answer tokens only, and their collator.

Order: the row groups (one object each) of all folders' train splits are listed from the Parquet
metadata alone; each epoch shuffles them with a generator seeded by (seed, epoch), cuts them into
windows of `shuffle_window` groups and shuffles the (row, task) examples within each window. Only
the current window's rows are in memory. The order is a function of (seed, epoch) and the files,
so a position (epoch, index) names an example, a resumed run continues at the saved position
without reading what it skips, and its data order is the uninterrupted run's.

Weighted folders (`TrainConfig.weights`): each folder has its own order as above (its own row
groups, seeded by (seed, epoch, folder)), and example k of the stream comes from the folder drawn
k-th from the weights (`folder_picks`: blocks of `MIX_BLOCK` draws, each seeded by (seed, block)).
The n-th example taken from a folder is its n-th in its own order, so example k is a function of
(seed, weights, k) and the files; the position is then (k // E, k % E), E being the examples of
one pass over every folder, and a resume at k counts the draws before it without reading rows.

Labels: -100 everywhere but the final assistant turn's answer and its end-of-turn token
(`<|im_end|>` for Qwen and InternVL, `<end_of_turn>` for Gemma 3), for every family's chat
template. The prompt is rendered with `add_generation_prompt=True` and must be a prefix of the
full conversation as text; the answer is found after it, so what a template puts between the two
(Qwen3-VL Thinking's empty `<think>\n\n</think>\n\n`) is context, not trained. The text up to
the answer must tokenize to a prefix of the conversation's tokens, and the processor's tokens
(image placeholders expanded, all in the prompt) must end with the tokenizer's tokens from the
answer on: the answer's position is then exact, whatever the family's image expansion. A
multi-turn world-feedback conversation (an earlier wrong answer, the feedback, the right answer)
is trained on its last answer only.

An example longer than `max_length` tokens is skipped and counted, never truncated: a cut answer
would teach a wrong one, and cut image tokens break the model's image alignment.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import torch
from torch.utils.data import IterableDataset

from eval.chat import columns_for, task_chat
from eval.data import info, shard_files
from eval.processor import load_processor
from factory.dataset.tasks import TASKS
from train.config import ConfigError

IGNORE = -100
log = logging.getLogger(__name__)


class EncodeError(ValueError):
    """A conversation whose answer span cannot be located (a chat template we cannot read)."""


# -- the answer span ---------------------------------------------------------------------------------
def _ids(tokenizer, text: str) -> list[int]:
    # the chat template renders every special token itself (Gemma's <bos> included): adding them
    # again would double the BOS of tokenizers that add one
    return list(tokenizer(text, add_special_tokens=False)["input_ids"])


def encode(processor, messages: list[dict], images: list, max_length: int | None = None) -> dict | None:
    """Token ids, labels and image tensors of one conversation ending with the assistant's answer;
    None when longer than `max_length` (see the module docstring)."""
    if not messages or messages[-1]["role"] != "assistant":
        raise EncodeError("the conversation must end with the assistant's answer")
    answer = "".join(p.get("text") or "" for p in messages[-1]["content"] if p.get("type") == "text")
    full = processor.apply_chat_template(messages, tokenize=False)
    prompt = processor.apply_chat_template(messages[:-1], tokenize=False, add_generation_prompt=True)
    if not full.startswith(prompt):
        raise EncodeError("the chat template renders the prompt differently with the answer appended")
    suffix = full[len(prompt):]
    at = suffix.find(answer.strip())  # templates that trim text parts (Gemma) render it stripped
    if not answer.strip() or at < 0:
        raise EncodeError("the answer text is not in the rendered conversation")
    begin = len(prompt) + at  # what the template puts between the prompt and the answer (Qwen3-VL's
    # empty think block) is context, like the prompt
    tail = suffix[at + len(answer.strip()):]  # the end of the turn, e.g. "<|im_end|>\n"
    end_marker = tail.strip()  # trained on (the model must learn to stop); trailing whitespace not
    cut = begin + len(answer.strip()) + (tail.index(end_marker) + len(end_marker) if end_marker else 0)
    tok = processor.tokenizer
    b_ids, t_ids, f_ids = _ids(tok, full[:begin]), _ids(tok, full[:cut]), _ids(tok, full)
    if t_ids[:len(b_ids)] != b_ids or f_ids[:len(t_ids)] != t_ids:
        raise EncodeError("the tokens before the answer are not a prefix of the conversation's tokens")
    enc = processor(text=[full], images=list(images) or None, return_tensors="pt", add_special_tokens=False)
    ids = enc["input_ids"][0]
    # the processor expands each image placeholder (into image tokens, and for Gemma and InternVL
    # begin/end markers too); images are in the prompt, so the answer and what follows it are the
    # tokenizer's tokens, shifted by the expansion
    extra = len(ids) - len(f_ids)
    if extra < 0 or ids[len(b_ids) + extra:].tolist() != f_ids[len(b_ids):]:
        raise EncodeError("the processor's tokens do not end with the tokenizer's tokens of the answer")
    if max_length is not None and len(ids) > max_length:
        return None
    labels = torch.full_like(ids, IGNORE)
    start, stop = len(b_ids) + extra, len(t_ids) + extra
    labels[start:stop] = ids[start:stop]
    out = {k: (v[0] if v.dim() > 1 and v.shape[0] == 1 and v.shape[-1] == len(ids) else v)
           for k, v in enc.items() if isinstance(v, torch.Tensor)}
    out["labels"] = labels
    return out


def collate(examples: list[dict], pad_id: int) -> dict:
    """A right-padded batch: per-token tensors padded (input ids with `pad_id`, labels with -100,
    masks with 0); image tensors (pixel_values, image_grid_thw) concatenated in example order."""
    seq_keys = [k for k, v in examples[0].items() if v.dim() == 1 and v.shape[0] == examples[0]["input_ids"].shape[0]]
    n = max(int(e["input_ids"].shape[0]) for e in examples)
    batch = {}
    for k in examples[0]:
        if k in seq_keys:
            fill = pad_id if k == "input_ids" else IGNORE if k == "labels" else 0
            t = torch.full((len(examples), n), fill, dtype=examples[0][k].dtype)
            for i, e in enumerate(examples):
                t[i, :e[k].shape[0]] = e[k]
            batch[k] = t
        else:
            batch[k] = torch.cat([e[k] for e in examples], dim=0)
    return batch


# -- the stream ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Group:
    """One Parquet row group of a train split (one object): where it is and what it yields."""

    file: str
    index: int
    rows: int
    tasks: tuple[str, ...]
    columns: tuple[str, ...]
    folder: int = 0
    """Position of its dataset folder in the stream's folders."""


def folder_tasks(folder) -> tuple[str, ...]:
    """The tasks a dataset folder provides: `meta/info.json` "tasks" (feedback folders: pose), else all."""
    return info(folder).available_tasks


def list_groups(folders, tasks, split: str = "train") -> list[Group]:
    """The non-empty row groups of `split` of every folder, in folder and file order (metadata only)."""
    groups = []
    for i, folder in enumerate(folders):
        use = tuple(t for t in tasks if t in folder_tasks(folder))
        if not use:
            continue
        for f in shard_files(folder, split):
            pf = pq.ParquetFile(f)
            names = set(pf.schema_arrow.names)
            cols = [c for t in use for c in columns_for(t)] + [c for c in ("feedback",) if c in names]
            for g in range(pf.num_row_groups):
                n = pf.metadata.row_group(g).num_rows
                if n:
                    groups.append(Group(str(f), g, n, use, tuple(dict.fromkeys(cols)), i))
    return groups


def epoch_order(groups: list[Group], seed: int, epoch: int, window: int,
                folder: int | None = None) -> list[tuple[int, int, str, int]]:
    """The epoch's examples as (group, row, task, window), in training order (see the module
    docstring); `folder`: the order of that folder's own `groups` in a weighted stream."""
    rng = np.random.default_rng([int(seed), int(epoch)] if folder is None else [int(seed), int(epoch), int(folder)])
    order = rng.permutation(len(groups)).tolist()
    out: list[tuple[int, int, str, int]] = []
    for w, start in enumerate(range(0, len(order), window)):
        items = [(g, r, t, w) for g in order[start:start + window] for r in range(groups[g].rows)
                 for t in groups[g].tasks]
        out += [items[i] for i in rng.permutation(len(items))]
    return out


MIX_BLOCK = 4096
"""Folder draws of a weighted stream made at once (one generator per block)."""
_MIX_KEY = 0x6D6978
"""Keeps the draws' generator apart from the epoch orders' ((seed, epoch) keys)."""


def folder_picks(weights, seed: int, block: int) -> np.ndarray:
    """The folder of each of the examples block * MIX_BLOCK ... (block + 1) * MIX_BLOCK - 1 of a
    weighted stream, drawn with probabilities weight / sum of weights."""
    p = np.asarray(weights, dtype=np.float64)
    rng = np.random.default_rng([int(seed), _MIX_KEY, int(block)])
    return rng.choice(len(p), size=MIX_BLOCK, p=p / p.sum())


_WORKER: dict = {}


def _worker_init(processor_path: str, max_pixels: int | None, max_length: int | None) -> None:
    # One thread per worker, as torch's own DataLoader workers do: with torch's default (a thread
    # per core) in every worker, 8 workers on 16 cores encoded 5.6 examples/s on the GPU machine
    # instead of the ~20/s per worker one thread gives.
    torch.set_num_threads(1)
    _WORKER.update(processor=load_processor(processor_path, max_pixels), max_length=max_length)


def _worker_encode(item):
    row, task, where = item
    messages, images, _ = task_chat(row, task, with_answer=True)
    return encode(_WORKER["processor"], messages, images, _WORKER["max_length"]), where


class ExampleStream(IterableDataset):
    """Encoded training examples, endlessly (epoch after epoch), from `position` on.

    `position` is (epoch, index of the next example in the epoch's order); after an example is
    yielded it is the position just past it (and past any skipped before it), so `position` after
    a step is where a resumed run restarts. `skipped` counts examples over `max_length`.

    `workers` > 0 encodes (PNG decoding, image resizing, tokenizing) in that many spawned
    processes, each loading the processor from `processor_path`, in order and at most a few
    examples ahead: the same examples in the same order as `workers=0`, faster on many cores.

    `weights` (one per folder): a weighted stream (see the module docstring); None or empty:
    every example of every folder once per epoch.
    """

    def __init__(self, folders, processor, tasks=TASKS, seed: int = 0, window: int = 16,
                 max_length: int | None = None, position: tuple[int, int] = (0, 0), split: str = "train",
                 workers: int = 0, processor_path=None, max_pixels: int | None = None, weights=None):
        self.folders = [str(Path(f)) for f in folders]
        self.processor, self.tasks, self.seed, self.window = processor, tuple(tasks), int(seed), int(window)
        self.max_length = max_length
        self.workers, self.processor_path, self.max_pixels = int(workers), processor_path, max_pixels
        if self.workers and processor_path is None:
            raise ValueError("workers need processor_path (each worker loads the processor)")
        self.groups = list_groups(self.folders, self.tasks, split)
        self.examples_per_epoch = sum(g.rows * len(g.tasks) for g in self.groups)
        if not self.examples_per_epoch:
            raise ConfigError(f"no {split} examples for tasks {', '.join(self.tasks)} in {', '.join(self.folders)}")
        self.weights = tuple(float(w) for w in weights) if weights else None
        if self.weights is not None:
            if len(self.weights) != len(self.folders):
                raise ConfigError(f"weights: one per folder ({len(self.folders)}), got {len(self.weights)}")
            self._members = [[g for g, grp in enumerate(self.groups) if grp.folder == i] for i in range(len(self.folders))]
            self._sizes = [sum(self.groups[g].rows * len(self.groups[g].tasks) for g in m) for m in self._members]
            empty = [f for f, n in zip(self.folders, self._sizes) if not n]
            if empty:
                raise ConfigError(f"{empty[0]}: no {split} examples for tasks {', '.join(self.tasks)}; a weighted "
                                  "folder must have some (leave it out of --data and --weights)")
        self.position = (int(position[0]), int(position[1]))
        self.skipped = 0
        self._cache: dict[int, list[dict]] = {}
        self._window: tuple | None = None
        self._block: tuple[int, np.ndarray] | None = None

    def _rows(self, g: int, cache: dict | None = None) -> list[dict]:
        """The rows of group `g`, read once into `cache` (default: the current window's)."""
        cache = self._cache if cache is None else cache
        if g not in cache:
            grp = self.groups[g]
            cache[g] = pq.ParquetFile(grp.file).read_row_group(grp.index, columns=list(grp.columns)).to_pylist()
        return cache[g]

    def rows(self, position: tuple[int, int]):
        """(row, task, (epoch, index after it), (group, row index, task)) from `position` on."""
        if self.weights is not None:
            yield from self._weighted_rows(position)
            return
        epoch, index = position
        while True:
            order = epoch_order(self.groups, self.seed, epoch, self.window)
            for i in range(index, len(order)):
                g, r, task, w = order[i]
                if self._window != (epoch, w):  # a new window: drop the rows of the last one
                    self._cache, self._window = {}, (epoch, w)
                after = (epoch, i + 1) if i + 1 < len(order) else (epoch + 1, 0)
                yield self._rows(g)[r], task, after, (g, r, task)
            epoch, index = epoch + 1, 0

    def _picks(self, block: int) -> np.ndarray:
        if self._block is None or self._block[0] != block:
            self._block = (block, folder_picks(self.weights, self.seed, block))
        return self._block[1]

    def _weighted_rows(self, position: tuple[int, int]):
        """`rows` of a weighted stream (see the module docstring)."""
        total = self.examples_per_epoch
        k = int(position[0]) * total + int(position[1])
        self._block = None
        taken = np.zeros(len(self.folders), dtype=np.int64)  # examples each folder gave before k
        for block in range(k // MIX_BLOCK):
            taken += np.bincount(self._picks(block), minlength=len(self.folders))
        taken += np.bincount(self._picks(k // MIX_BLOCK)[:k % MIX_BLOCK], minlength=len(self.folders))
        orders: dict[int, tuple[int, list]] = {}
        caches: dict[int, tuple[tuple[int, int], dict[int, list[dict]]]] = {}
        while True:
            f = int(self._picks(k // MIX_BLOCK)[k % MIX_BLOCK])
            epoch, i = divmod(int(taken[f]), self._sizes[f])
            if orders.get(f, (None,))[0] != epoch:
                members = self._members[f]
                orders[f] = (epoch, epoch_order([self.groups[g] for g in members], self.seed, epoch, self.window, f))
            local, r, task, w = orders[f][1][i]
            g = self._members[f][local]
            if caches.get(f, ((None,),))[0] != (epoch, w):  # a new window of this folder: drop the last one's rows
                caches[f] = ((epoch, w), {})
            row = self._rows(g, caches[f][1])[r]
            taken[f] += 1
            k += 1
            yield row, task, divmod(k, total), (g, r, task)

    def raw(self):
        """(messages, images, answer, (group, row, task)) from `position` on, advancing it."""
        for row, task, after, where in self.rows(self.position):
            messages, images, answer = task_chat(row, task, with_answer=True)
            self.position = after
            yield messages, images, answer, where

    def _encoded(self):
        """(example or None, position after it, where) in order, encoded here or by the workers."""
        if not self.workers:
            for row, task, after, where in self.rows(self.position):
                messages, images, _ = task_chat(row, task, with_answer=True)
                yield encode(self.processor, messages, images, self.max_length), after, where
            return
        pool = mp.get_context("spawn").Pool(self.workers, initializer=_worker_init,
                                            initargs=(str(self.processor_path), self.max_pixels, self.max_length))
        try:
            items = self.rows(self.position)
            pending: deque = deque()
            while True:
                while len(pending) < 4 * self.workers:  # bounded read-ahead, kept in order
                    row, task, after, where = next(items)
                    pending.append((pool.apply_async(_worker_encode, ((row, task, where),)), after))
                result, after = pending.popleft()
                ex, where = result.get()
                yield ex, after, where
        finally:
            pool.terminate()

    def __iter__(self):
        run = 0  # examples read since the last one kept: a whole epoch of skips would never end
        for ex, after, where in self._encoded():
            self.position = after
            if ex is None:
                self.skipped += 1
                run += 1
                if self.skipped in (1, 10, 100) or self.skipped % 1000 == 0:
                    log.warning("skipped %d example(s) longer than max_length=%s tokens (latest: %s)",
                                self.skipped, self.max_length, where)
                if run >= self.examples_per_epoch:
                    raise ConfigError(f"every example is longer than max_length={self.max_length} tokens; "
                                      "raise --max-length or lower --max-pixels")
                continue
            run = 0
            yield ex
