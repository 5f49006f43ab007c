"""A small multilayer perceptron in numpy: what the manipulation envs' learner fits (physics.learn) and what its
policy files hold (kind 'mlp'). No torch: a policy is a few matrices, it learns on a CPU in minutes and acts in
microseconds. No rospy.

    net = Mlp.new(inputs=29, outputs=4, hidden=(256, 256), seed=0)
    net.fit_step(x, y)          # one Adam step of the mean squared error on a batch
    net.act_batch(x)            # (N, outputs) in [-1, 1] (tanh)

The inputs are normalised by the mean and spread the network holds (set from the data it first learns on), the
hidden layers are ReLU, the output tanh: actions of a Box(-1, 1).
"""
from __future__ import annotations

import dataclasses

import numpy as np

KIND = 'mlp'


@dataclasses.dataclass(eq=False)
class Mlp:
    """weights[k] (inputs_k, outputs_k) and biases[k] (outputs_k,), the input's mean and scale (inputs,)."""
    weights: list[np.ndarray]
    biases: list[np.ndarray]
    mean: np.ndarray
    scale: np.ndarray
    kind: str = KIND
    _adam: dict | None = dataclasses.field(default=None, repr=False)

    @classmethod
    def new(cls, inputs: int, outputs: int, hidden=(256, 256), seed: int = 0) -> 'Mlp':
        rng = np.random.default_rng(seed)
        sizes = [inputs, *hidden, outputs]
        weights = [rng.normal(0.0, np.sqrt(2.0 / a), (a, b)) for a, b in zip(sizes[:-1], sizes[1:])]
        weights[-1] *= 0.01                    # actions near 0 at first
        biases = [np.zeros(b) for b in sizes[1:]]
        return cls(weights, biases, np.zeros(inputs), np.ones(inputs))

    @property
    def inputs(self) -> int:
        return self.weights[0].shape[0]

    @property
    def outputs(self) -> int:
        return self.weights[-1].shape[1]

    def normalise_by(self, x: np.ndarray) -> None:
        """The input's mean and scale from data x (N, inputs); a constant input gets scale 1."""
        self.mean = x.mean(axis=0)
        spread = x.std(axis=0)
        self.scale = np.where(spread > 1e-6, spread, 1.0)

    def _forward(self, x: np.ndarray) -> list[np.ndarray]:
        h = (x - self.mean) / self.scale
        layers = [h]
        for k, (w, b) in enumerate(zip(self.weights, self.biases)):
            h = h @ w + b
            h = np.tanh(h) if k == len(self.weights) - 1 else np.maximum(h, 0.0)
            layers.append(h)
        return layers

    def act_batch(self, x) -> np.ndarray:
        """(N, outputs) for inputs (N, inputs)."""
        return self._forward(np.asarray(x, dtype=np.float64))[-1]

    def act(self, x) -> np.ndarray:
        return self.act_batch(np.asarray(x, dtype=np.float64)[None])[0]

    def fit_step(self, x: np.ndarray, y: np.ndarray, rate: float = 1e-3) -> float:
        """One Adam step on the mean squared error of (x, y); the loss before it."""
        layers = self._forward(x)
        out = layers[-1]
        error = out - y
        loss = float(np.mean(error ** 2))
        grad = 2.0 * error / error.size * (1.0 - out ** 2)            # through tanh
        grads_w, grads_b = [None] * len(self.weights), [None] * len(self.weights)
        for k in range(len(self.weights) - 1, -1, -1):
            grads_w[k] = layers[k].T @ grad
            grads_b[k] = grad.sum(axis=0)
            if k:
                grad = (grad @ self.weights[k].T) * (layers[k] > 0.0)
        self._adam_step(grads_w + grads_b, rate)
        return loss

    def _adam_step(self, grads: list[np.ndarray], rate: float, beta1: float = 0.9, beta2: float = 0.999) -> None:
        params = self.weights + self.biases
        if self._adam is None:
            self._adam = {'m': [np.zeros_like(p) for p in params], 'v': [np.zeros_like(p) for p in params], 't': 0}
        adam = self._adam
        adam['t'] += 1
        t = adam['t']
        correction = rate * np.sqrt(1.0 - beta2 ** t) / (1.0 - beta1 ** t)
        for p, g, m, v in zip(params, grads, adam['m'], adam['v']):
            m *= beta1
            m += (1.0 - beta1) * g
            v *= beta2
            v += (1.0 - beta2) * g * g
            p -= correction * m / (np.sqrt(v) + 1e-8)

    def arrays(self) -> dict[str, np.ndarray]:
        """What a policy file holds: layer{k} (inputs_k + 1, outputs_k), the weights with the bias as the last row,
        and norm (2, inputs): the mean and the scale."""
        out = {'norm': np.stack([self.mean, self.scale])}
        for k, (w, b) in enumerate(zip(self.weights, self.biases)):
            out[f'layer{k}'] = np.vstack([w, b[None]])
        return out

    @classmethod
    def from_arrays(cls, arrays: dict) -> 'Mlp':
        layers = [np.asarray(arrays[f'layer{k}'], dtype=np.float64)
                  for k in range(sum(1 for name in arrays if name.startswith('layer')))]
        norm = np.asarray(arrays['norm'], dtype=np.float64)
        return cls([a[:-1].copy() for a in layers], [a[-1].copy() for a in layers], norm[0].copy(), norm[1].copy())
