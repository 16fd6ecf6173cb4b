"""The effective radial phase of a fabricated lens from its measured PSFs (``metalens psf retrieve``).

Model. The lens imparts φ(r) = φ_nominal(r) + δ(r), with the perturbation

    δ(r) = Σ_k c_k · R_{2k}^0(ρ),   ρ = r/(D/2),   k = 1..K

R_n^0 the Zernike radial polynomials (R(1) = 1, not RMS-normalised: the RMS of c·R_n^0 over the
pupil is |c|/√(n + 1)): defocus R_2^0 = 2ρ² − 1, primary spherical R_4^0, secondary R_6^0, ...
A geometric phase is the same at every wavelength, so one δ (radians of phase) serves every PSF
of the cube. The defocus term also absorbs an error in the lens-to-sensor distance. Each measured
PSF m (one depth, one wavelength) is modelled as

    model_m = s_m · shift(P_m(c), t_m) + b_m

P_m the sensor PSF of the lens with that phase (``optics.psf.compute_psf``, radial propagator,
float64) on the cube's own pixels (its pitch, its window, the axis at pixel (N//2, N//2)),
computed on a window ``MARGIN_PIXELS`` wider a side and cropped after the shift; t_m a sub-pixel
shift (a Fourier phase ramp), s_m a scale (the cube's normalisation), b_m a constant background.
Shift and background are optional (``nuisance``); the scale is always fitted.

Fit. Levenberg-Marquardt (damping λ·diag(JᵀJ)) on the weighted residuals (measured − model)/σ_m,
started at δ = 0 with each PSF's scale and background from linear least squares against the
nominal PSF and no shift. The Jacobian columns of the K coefficients come from forward-mode
automatic differentiation through the propagator (one pass per coefficient); those of the
nuisance parameters, each of which moves one PSF only, from one forward-mode pass of the cheap
shift-scale-background step per kind. Stage 1 weighs each PSF by its norm (σ_m ∝ ‖M_m‖: the
relative L2 error); at its end each pixel's noise variance is modelled as σ² = a_m + b_m·model
(a read-noise floor and a shot-noise slope, fitted per PSF to its squared residuals) and stage 2
refits with those weights, so that PSFs and pixels count by their noise. (With one σ per PSF,
Poisson data gave uncertainties 2-3× too small: bright pixels are the noisiest.)

Uncertainty. The coefficients' covariance is the Gauss-Newton (JᵀWJ)⁻¹·χ²_red at the solution
(W = 1/σ², σ from the residual: the cube's own noise plus anything the model misses), of which
the coefficients' block is reported as 1-σ uncertainties and correlations. The condition number
is that of the coefficients' block of JᵀWJ after eliminating the nuisance parameters (their Schur
complement), its columns scaled to unit diagonal: 1 for independent terms.

Refusals (InputError, before the fit unless said). A cube of one depth and one wavelength: an
intensity alone does not tell δ from −δ (the conjugate pupil, the twin image, gives the same PSF
for a radially symmetric lens in focus), and different depths or wavelengths (a diffractive lens
focuses each wavelength elsewhere) break the tie. Non-finite values; a PSF without light; frames
imported with saturated pixels (the header's ``frames[].saturated_pixels``); pixels wider than
the lens's Airy core at the longest wavelength (1.22·λ/NA: each in-focus PSF a pixel or two), or a
window narrower than ``MIN_PIXELS`` or than two Airy cores; a 2-D design (the model is radial).
A degenerate fit: when, at the nominal, the Schur complement's condition number exceeds
``MAX_CONDITION`` (or a term moves no pixel), the fit is refused naming the terms that the cube
does not constrain (those dominating the weakest direction), rather than reporting unbounded
uncertainties.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.autograd.forward_ad as fwad

from metalens_cli.errors import InputError
from metalens_cli.io.resources import Estimate
from metalens_cli.io.units import format_length
from metalens_cli.optics.lens import Metalens
from metalens_cli.optics.psf import compute_psf, estimate_psf
from metalens_cli.optics.sampling import PsfGrid, check_lens_sampling

NUISANCE = ("shift", "background")  # optional per-PSF parameters; the scale is always fitted
TERM_NAMES = ("defocus", "primary spherical", "secondary spherical", "tertiary spherical")
MAX_TERMS = 10  # up to R_20^0
MARGIN_PIXELS = 4  # the model window's extra pixels a side, cropped after the sub-pixel shift
MIN_PIXELS = 8  # a window narrower than this holds no shape to fit
MAX_CONDITION = 1e10  # a coefficient block worse conditioned than this at the nominal is degenerate
MAX_SAMPLES = 5e7  # PSFs × pixels: the Jacobian is (K + 4) float64 values per sample
FTOL = 1e-9  # stop when an accepted step lowers the cost by less than this fraction
XTOL = 1e-9  # ... or moves no parameter by more than this (relative, in units of its scale)
MAX_DAMPING = 1e12
NOISE_FLOOR = 0.01  # stage 2's σ² at least this fraction of the PSF's σ² at its peak
PASSES_PER_ITERATION = 3  # plain passes per iteration besides the K forward-mode ones (the step and rejected steps)
TYPICAL_ITERATIONS = 15
# seconds per forward-mode pass, at least (the radial path's fixed costs, float64 and dual numbers): measured
# 2 s for the 60 µm test lens (6 PSFs of 40², 12 Jacobians of 4 terms, 1 core) and 15 s for the paper's lens
# (6 PSFs of 64², 11 Jacobians, 2 busy cores), where estimate_psf plans 0.02 s a pass
PASS_OVERHEAD_S = 0.08
PASS_FACTOR = 3.0  # forward-mode passes over estimate_psf's forward


@dataclass
class PhaseRetrieval:
    """The result of :func:`retrieve_phase`.

    Attributes:
        theta: the retrieved radial θ (rad) = (φ_nominal + δ)/2 at r = k·pitch, the nominal lens's
            samples (a design spec as a .npy).
        delta: δ (rad) at the same radii.
        terms: per term: ``name``, ``n`` (the radial order), ``coefficient_rad``, ``sigma_rad``,
            ``coefficient_waves`` and ``sigma_waves`` (radians / 2π).
        covariance_rad2: (K, K) coefficients' covariance (rad²).
        correlation: (K, K) their correlation matrix.
        psfs: per measured PSF: ``depth_m`` (None: infinity), ``wavelength_m``,
            ``relative_l2_nominal`` (‖M − model‖/‖M‖ at δ = 0, least-squares scale and background,
            no shift), ``relative_l2`` (after the fit), ``noise_sigma`` (RMS of the pixels' σ, the
            cube's units), ``noise_model`` (``read_variance`` a, ``shot_slope`` b: σ² = a + b·model),
            ``shift_px`` [dy, dx], ``scale``, ``background``.
        condition_number: of the normalised Schur complement at the solution (module docstring).
        chi2_reduced: Σ r²/σ² per degree of freedom at the solution (≈ 1 by construction).
        iterations: Levenberg-Marquardt iterations (Jacobians), both stages.
        converged: whether the fit stopped by its tolerances (not by the iteration limit).
        seconds: wall time of the fit.
        nuisance: the optional per-PSF parameters fitted.
        warnings: one line each.
    """

    theta: np.ndarray
    delta: np.ndarray
    terms: list[dict]
    covariance_rad2: np.ndarray
    correlation: np.ndarray
    psfs: list[dict]
    condition_number: float
    chi2_reduced: float
    iterations: int
    converged: bool
    seconds: float
    nuisance: tuple[str, ...]
    warnings: list[str] = field(default_factory=list)


def zernike_radial(n: int, rho):
    """Zernike radial polynomial R_n^0(ρ) for even n ≥ 0 (R(1) = 1), of a numpy array or tensor.

    Examples:
        >>> [float(zernike_radial(n, np.array(1.0))) for n in (2, 4, 6)]
        [1.0, 1.0, 1.0]
        >>> float(zernike_radial(4, np.array(0.0)))
        1.0
    """
    if n < 0 or n % 2:
        raise InputError("n", f"{n} is not an even order", "an even radial order ≥ 0")
    m = n // 2
    return sum(
        (-1) ** s * math.factorial(n - s) / (math.factorial(s) * math.factorial(m - s) ** 2) * rho ** (n - 2 * s)
        for s in range(m + 1)
    )


def term_name(k: int) -> str:
    """Name of term k (from 0): "Z(2,0) defocus", "Z(4,0) primary spherical", ..., "Z(12,0)"."""
    n = 2 * (k + 1)
    return f"Z({n},0)" + (f" {TERM_NAMES[k]}" if k < len(TERM_NAMES) else "")


def perturbation_basis(lens: Metalens, terms: int) -> np.ndarray:
    """(K, samples) R_{2k}^0(r/(D/2)) at the lens's radial samples r = k·pitch (rad per unit coefficient)."""
    r = np.arange(lens.theta.shape[0]) * lens.pitch_m
    rho = r / lens.radius_m
    return np.stack([zernike_radial(2 * (k + 1), rho) for k in range(terms)])


def numerical_aperture(lens: Metalens, distance_m: float) -> float:
    """sin of the marginal ray's angle, (D/2)/√((D/2)² + d²)."""
    return lens.radius_m / math.hypot(lens.radius_m, distance_m)


def check_retrievable(
    psf: np.ndarray,
    wavelengths_m,
    depths_m,
    pixel_pitch_m: float,
    lens: Metalens,
    distance_m: float,
    metadata: dict | None = None,
    field_name: str = "MEASURED",
) -> None:
    """Refuse (InputError naming ``field_name`` or ``--design``), before any PSF is computed, a
    cube that cannot constrain the phase (module docstring): shape, values, saturation, pitch."""
    psf = np.asarray(psf)
    if psf.ndim != 4 or psf.shape[-1] != psf.shape[-2]:
        raise InputError(field_name, f"PSFs of shape {psf.shape}", "(depths, wavelengths, N, N)")
    d_count, w_count, n = psf.shape[0], psf.shape[1], psf.shape[-1]
    if (d_count, w_count) != (len(depths_m), len(wavelengths_m)):
        raise InputError(field_name, "its axes disagree with its PSFs", "one PSF per (depth, wavelength)")
    if not lens.radial:
        raise InputError("--design", "a 2-D rotation map", "a radially symmetric design (the fit is radial)")
    if d_count == 1 and w_count == 1:
        raise InputError(
            field_name,
            "one depth and one wavelength: an intensity alone cannot tell the phase error δ from −δ (the conjugate "
            "pupil, the twin image, gives the same PSF for a radially symmetric lens)",
            "a cube of two or more depths or wavelengths (phase diversity)",
        )
    if not np.all(np.isfinite(psf)):
        raise InputError(field_name, f"{int(np.sum(~np.isfinite(psf)))} NaN or infinite values", "finite PSFs")
    sums = psf.reshape(d_count, w_count, -1).astype(np.float64).sum(-1)
    if np.any(sums <= 0):
        i, j = np.argwhere(sums <= 0)[0]
        raise InputError(
            field_name,
            f"the PSF at {wavelengths_m[j] * 1e9:g} nm, {_depth_text(depths_m[i])} holds no light",
            "PSFs with light",
        )
    if psf.size > MAX_SAMPLES:
        raise InputError(
            field_name,
            f"{d_count * w_count} PSFs of {n}² pixels: {psf.size:.3g} samples, over the {MAX_SAMPLES:.0g} a fit holds",
            "fewer PSFs or a smaller window (psf import --pixels)",
        )
    saturated = [f for f in (metadata or {}).get("frames", []) or [] if (f or {}).get("saturated_pixels")]
    if saturated:
        names = ", ".join(str(f.get("file", "?")) for f in saturated[:3]) + (" ..." if len(saturated) > 3 else "")
        raise InputError(
            field_name,
            f"{len(saturated)} of its frames were imported with saturated pixels ({names}): a clipped core "
            "biases the phase",
            "a cube imported from frames below saturation",
        )
    na = numerical_aperture(lens, distance_m)
    core_long = 1.22 * max(wavelengths_m) / na
    if pixel_pitch_m > core_long:
        raise InputError(
            field_name,
            f"its pixels of {format_length(pixel_pitch_m)} are wider than the lens's Airy core (1.22·λ/NA = "
            f"{format_length(core_long)} at {max(wavelengths_m) * 1e9:g} nm, NA {na:.3g}): the PSFs are not sampled",
            "a pixel pitch (camera pitch / magnification) below the Airy core",
        )
    if n < MIN_PIXELS or n * pixel_pitch_m < 2 * core_long:
        raise InputError(
            field_name,
            f"its window of {n} pixels ({format_length(n * pixel_pitch_m)}) is too small for the PSFs",
            f"at least {MIN_PIXELS} pixels and two Airy cores ({format_length(2 * core_long)}) across",
        )


def estimate_retrieval(lens: Metalens, grid: PsfGrid, terms: int, max_iterations: int) -> Estimate:
    """Memory (the PSFs' own and the Jacobian's float64 columns) and time (per iteration K
    forward-mode passes and a few plain ones, from ``optics.psf.estimate_psf``) of a fit on
    ``grid`` (the model's window)."""
    cost = estimate_psf(lens, grid, propagator="radial", dtype=torch.float64)
    samples = grid.count * grid.pixels**2
    memory = 3 * cost.memory_bytes + samples * 8 * (terms + 4 + 12)
    per_pass = max(PASS_FACTOR * (cost.seconds - cost.setup_seconds), PASS_OVERHEAD_S)
    per_iteration = (terms + PASSES_PER_ITERATION) * per_pass
    return Estimate(
        f"psf retrieve of {grid.count} PSFs of {grid.pixels}² pixels with {terms} terms",
        int(memory),
        "--max-iterations",
        cost.setup_seconds + TYPICAL_ITERATIONS * per_iteration,
        seconds_max=cost.setup_seconds + 2 * max_iterations * per_iteration,
    )


def model_grid(wavelengths_m, depths_m, pixels: int, pixel_pitch_m: float, distance_m: float) -> PsfGrid:
    """The window the model is computed on: the cube's, ``MARGIN_PIXELS`` wider a side."""
    return PsfGrid(
        [float(w) for w in wavelengths_m],
        [float(d) for d in depths_m],
        pixels + 2 * MARGIN_PIXELS,
        pixel_pitch_m,
        distance_m,
    )


def retrieve_phase(
    psf: np.ndarray,
    wavelengths_m,
    depths_m,
    pixel_pitch_m: float,
    lens: Metalens,
    *,
    distance_m: float | None = None,
    terms: int = 4,
    nuisance: tuple[str, ...] = NUISANCE,
    max_iterations: int = 50,
    device: str | torch.device = "cpu",
    progress: Callable[[int, int], None] | None = None,
    metadata: dict | None = None,
) -> PhaseRetrieval:
    """Fit the radial phase perturbation δ of ``lens`` to measured PSFs (module docstring).

    Args:
        psf: (D, W, N, N) measured PSFs (any normalisation), the axis at pixel (N//2, N//2).
        wavelengths_m: the W wavelengths (m).
        depths_m: the D source depths (m; ``inf``: a plane wave).
        pixel_pitch_m: the cube's pixel pitch in the lens's sensor plane (m).
        lens: the nominal lens (radial θ), the starting point δ = 0.
        distance_m: lens-to-sensor distance (m); None: the lens's focal length.
        terms: K, the number of even Zernike radial terms (1 to ``MAX_TERMS``).
        nuisance: optional per-PSF parameters fitted besides the scale: "shift", "background".
        max_iterations: Levenberg-Marquardt iterations per stage.
        device: the torch device of the propagation.
        progress: called as ``progress(done, total)`` after each iteration.
        metadata: the cube's header (saturation is read from its ``frames``).

    Returns:
        The :class:`PhaseRetrieval`.

    Raises:
        InputError: a cube that cannot constrain the phase, naming MEASURED; unconstrained terms,
            naming --terms; a 2-D design, naming --design.
    """
    start = time.perf_counter()
    if not isinstance(terms, int) or not 1 <= terms <= MAX_TERMS:
        raise InputError("--terms", f"{terms!r}", f"1 to {MAX_TERMS} terms")
    unknown = [k for k in nuisance if k not in NUISANCE]
    if unknown:
        raise InputError("--nuisance", f"unknown {', '.join(unknown)}", f"a subset of {', '.join(NUISANCE)}, or none")
    distance = float(distance_m if distance_m is not None else lens.focal_length_m or 0.0)
    if distance <= 0:
        raise InputError("--f", "the design has no lens-to-sensor distance", "--f 4mm or a design with f")
    depths = [float(d) for d in np.ravel(depths_m)]
    waves = [float(w) for w in np.ravel(wavelengths_m)]
    check_retrievable(psf, waves, depths, pixel_pitch_m, lens, distance, metadata)
    fit = _Fit(np.asarray(psf, np.float64), waves, depths, pixel_pitch_m, lens, distance, terms, nuisance, device)
    total = 2 * max_iterations
    done = 0

    def tick():
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, total)

    fit.check_constrained()
    nominal_l2 = fit.relative_l2()
    converged_1 = fit.levenberg_marquardt(max_iterations, tick)
    fit.reweight()
    converged_2 = fit.levenberg_marquardt(max_iterations, tick)
    if progress is not None:
        progress(total, total)
    return fit.result(nominal_l2, converged_1 and converged_2, done, time.perf_counter() - start)


class _Fit:
    """The state of one fit: data, weights, parameters, the model and its Jacobian."""

    def __init__(self, psf, wavelengths_m, depths_m, pixel_pitch_m, lens, distance_m, terms, nuisance, device):
        self.device = torch.device(device)
        d_count, w_count, n = psf.shape[0], psf.shape[1], psf.shape[-1]
        self.n, self.count = n, d_count * w_count
        self.depths, self.waves = depths_m, wavelengths_m
        self.data = torch.from_numpy(psf.reshape(self.count, n, n)).to(self.device)
        self.lens = Metalens(lens.theta.detach().double().cpu(), lens.pitch_m, lens.aperture_m, lens.focal_length_m)
        self.grid = model_grid(wavelengths_m, depths_m, n, pixel_pitch_m, distance_m)
        self.plan_frequency = 2 ** (2 / 16) * check_lens_sampling(self.lens, wavelengths_m, depths_m, False)
        self.basis = torch.from_numpy(perturbation_basis(self.lens, terms))
        self.terms = terms
        self.nuisance = tuple(nuisance)
        # per-PSF slots: dy, dx (pixels), a (scale = s0·(1 + a)), beta (background = beta·bref)
        self.free = [0, 1] * ("shift" in nuisance) + [2] + [3] * ("background" in nuisance)
        # per pixel, 1/σ; stage 1: 1/‖M_m‖ (each PSF's relative L2 error)
        self.weights = (1 / torch.linalg.vector_norm(self.data, dim=(-2, -1)))[:, None, None].expand(-1, n, n)
        self.noise_model = torch.zeros(self.count, 2, dtype=torch.float64)
        self.coefficients = torch.zeros(terms, dtype=torch.float64)
        self.slots = torch.zeros(self.count, 4, dtype=torch.float64, device=self.device)
        self.bref = self.data.abs().amax(dim=(-2, -1))
        nominal = self._crop(self._simulate(self.coefficients))
        self.s0, background = self._linear_start(nominal)
        self.slots[:, 3] = background / self.bref
        ky = torch.fft.fftfreq(n + 2 * MARGIN_PIXELS, dtype=torch.float64, device=self.device)
        self.ky, self.kx = ky[:, None], ky[None, :]
        self.damping = 1e-3

    # --------------------------------------------------------------------------------- model

    def _simulate(self, coefficients: torch.Tensor) -> torch.Tensor:
        """(M, n + 2·margin, …) PSFs of the lens with δ = Σ c_k R_k (differentiable in c, forward mode too)."""
        theta = self.lens.theta + (coefficients @ self.basis) / 2
        trial = Metalens(theta, self.lens.pitch_m, self.lens.aperture_m, self.lens.focal_length_m)
        result = compute_psf(
            trial,
            self.grid,
            propagator="radial",
            dtype=torch.float64,
            device=self.device,
            plan_frequency=self.plan_frequency,
        )
        big = self.grid.pixels
        return result.psf.reshape(self.count, big, big)

    def _crop(self, images: torch.Tensor) -> torch.Tensor:
        m = MARGIN_PIXELS
        return images[:, m : m + self.n, m : m + self.n]

    def _shifted(self, images: torch.Tensor, dy: torch.Tensor, dx: torch.Tensor) -> torch.Tensor:
        """Each image moved by (dy, dx) pixels (content at p goes to p + d) by a Fourier phase ramp."""
        ramp = torch.exp(-2j * math.pi * (self.ky * dy[:, None, None] + self.kx * dx[:, None, None]))
        return torch.fft.ifft2(torch.fft.fft2(images) * ramp).real

    def _model(self, simulated: torch.Tensor, slots: torch.Tensor) -> torch.Tensor:
        """s·shift(P, t) + b on the cube's window, (M, n, n)."""
        shifted = self._crop(self._shifted(simulated, slots[:, 0], slots[:, 1]))
        scale = self.s0 * (1 + slots[:, 2])
        return scale[:, None, None] * shifted + (slots[:, 3] * self.bref)[:, None, None]

    def _linear_start(self, nominal: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Per PSF, the scale and background (if fitted) minimising ‖M − s·P − b‖ (nominal P, no shift)."""
        p = nominal.reshape(self.count, -1)
        m = self.data.reshape(self.count, -1)
        if "background" not in self.nuisance:
            scale = (p * m).sum(-1) / (p * p).sum(-1)
            return scale, torch.zeros_like(scale)
        design = torch.stack([p, torch.ones_like(p)], -1)  # (M, pixels, 2)
        solution = torch.linalg.lstsq(design, m[..., None]).solution[..., 0]
        scale = solution[:, 0]
        fallback = m.sum(-1) / p.sum(-1)
        ok = scale > 0
        return torch.where(ok, scale, fallback), torch.where(ok, solution[:, 1], torch.zeros_like(scale))

    def residual(self, coefficients=None, slots=None, simulated=None) -> torch.Tensor:
        """(M, n·n) weighted residuals (M − model)/σ_m."""
        coefficients = self.coefficients if coefficients is None else coefficients
        slots = self.slots if slots is None else slots
        with torch.no_grad():
            simulated = self._simulate(coefficients) if simulated is None else simulated
            model = self._model(simulated, slots)
        return ((self.data - model) * self.weights).reshape(self.count, -1)

    def relative_l2(self, coefficients=None, slots=None) -> torch.Tensor:
        """(M,) ‖M − model‖/‖M‖ per PSF."""
        r = self.residual(coefficients, slots) / self.weights.reshape(self.count, -1)
        return torch.linalg.vector_norm(r, dim=-1) / torch.linalg.vector_norm(self.data.reshape(self.count, -1), dim=-1)

    def jacobian(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The weighted residuals (M, P_pix), the model's Jacobian over the coefficients (M, P_pix, K)
        and over each PSF's free slots (M, P_pix, q), weighted (forward-mode AD)."""
        columns = []
        simulated = None
        for k in range(self.terms):
            tangent = torch.zeros_like(self.coefficients)
            tangent[k] = 1
            with fwad.dual_level():
                dual = self._simulate(fwad.make_dual(self.coefficients, tangent))
                model = self._model(dual, self.slots)
                plain, derivative = fwad.unpack_dual(model)
                if simulated is None:
                    simulated = fwad.unpack_dual(dual).primal.detach()
            columns.append(derivative.detach().reshape(self.count, -1))
        w = self.weights.reshape(self.count, -1, 1)
        jc = torch.stack(columns, -1) * w
        slot_columns = []
        for slot in self.free:
            tangent = torch.zeros_like(self.slots)
            tangent[:, slot] = 1
            with fwad.dual_level():
                model = self._model(simulated, fwad.make_dual(self.slots, tangent))
                derivative = fwad.unpack_dual(model).tangent
            slot_columns.append(derivative.detach().reshape(self.count, -1))
        jn = torch.stack(slot_columns, -1) * w
        r = ((self.data - plain.detach()) * self.weights).reshape(self.count, -1).cpu()
        return r, jc.cpu(), jn.cpu()

    # ------------------------------------------------------------------------------- algebra

    def normal_equations(self, r, jc, jn) -> tuple[np.ndarray, np.ndarray]:
        """JᵀJ (P × P) and Jᵀr (P,), parameters ordered [c_1..c_K, PSF 0's slots, PSF 1's, ...]."""
        k, q, m = self.terms, len(self.free), self.count
        size = k + q * m
        a = np.zeros((size, size))
        a[:k, :k] = torch.einsum("mik,mil->kl", jc, jc).numpy()
        cross = torch.einsum("mik,mia->kma", jc, jn).reshape(k, m * q).numpy()
        a[:k, k:], a[k:, :k] = cross, cross.T
        blocks = torch.einsum("mia,mib->mab", jn, jn).numpy()
        for i in range(m):
            a[k + i * q : k + (i + 1) * q, k + i * q : k + (i + 1) * q] = blocks[i]
        g = np.concatenate([torch.einsum("mik,mi->k", jc, r).numpy(), torch.einsum("mia,mi->ma", jn, r).reshape(-1)])
        return a, g

    def check_constrained(self) -> None:
        """Refuse (InputError naming --terms) when the nominal Jacobian leaves terms unconstrained."""
        r, jc, jn = self.jacobian()
        a, _ = self.normal_equations(r, jc, jn)
        check_constrained(a, self.terms, len(self.free), self.count)

    def _apply(self, step: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        k, q = self.terms, len(self.free)
        coefficients = self.coefficients + torch.from_numpy(step[:k])
        slots = self.slots.clone()
        slots[:, self.free] += torch.from_numpy(step[k:].reshape(self.count, q)).to(self.device)
        return coefficients, slots

    def levenberg_marquardt(self, max_iterations: int, tick: Callable[[], None]) -> bool:
        """Iterate from the current parameters; True when a tolerance stopped it."""
        self.damping = 1e-3
        for _ in range(max_iterations):
            r, jc, jn = self.jacobian()
            a, g = self.normal_equations(r, jc, jn)
            cost = 0.5 * float((r**2).sum())
            diag = np.maximum(np.diag(a), 1e-12 * max(float(np.diag(a).max()), 1e-300))
            while True:
                try:
                    step = np.linalg.solve(a + self.damping * np.diag(diag), g)
                except np.linalg.LinAlgError:
                    step = None
                if step is not None and np.all(np.isfinite(step)):
                    coefficients, slots = self._apply(step)
                    trial = 0.5 * float((self.residual(coefficients, slots) ** 2).sum())
                    if trial < cost:
                        break
                self.damping *= 4
                if self.damping > MAX_DAMPING:
                    tick()
                    return True  # no step lowers the cost: at a minimum to the precision of the model
            self.coefficients, self.slots = coefficients, slots
            self.damping = max(self.damping / 3, 1e-12)
            tick()
            moved = np.abs(step) * np.sqrt(diag) / max(math.sqrt(2 * cost), 1e-300)
            if cost - trial <= FTOL * cost or float(moved.max()) <= XTOL:
                return True
        return False

    def reweight(self) -> None:
        """Stage 2's weights: per pixel 1/σ with σ² = a_m + b_m·max(model, 0), a read-noise floor and
        a shot-noise slope fitted per PSF to its squared residuals (least squares; b ≥ 0; σ² at
        least ``NOISE_FLOOR`` of its value at the PSF's peak), scaled by pixels per degree of freedom."""
        with torch.no_grad():
            model = self._model(self._simulate(self.coefficients), self.slots)
        squared = (self.data - model).reshape(self.count, -1) ** 2
        light = model.reshape(self.count, -1).clamp(min=0)
        dof = self.n**2 - len(self.free) - self.terms / self.count
        for m in range(self.count):
            design = torch.stack([torch.ones_like(light[m]), light[m]], -1)
            a, b = torch.linalg.lstsq(design, squared[m][:, None]).solution[:, 0]
            if b < 0:
                a, b = squared[m].mean(), torch.zeros_like(b)
            self.noise_model[m] = torch.stack([a, b]).cpu() * (self.n**2 / dof)
        a, b = self.noise_model[:, :1].to(self.device), self.noise_model[:, 1:].to(self.device)
        peak = a + b * light.amax(-1, keepdim=True)
        variance = torch.maximum(a + b * light, NOISE_FLOOR * peak)
        norms = torch.linalg.vector_norm(self.data.reshape(self.count, -1), dim=-1, keepdim=True)
        floor = (1e-12 * norms / self.n) ** 2
        self.weights = (1 / torch.sqrt(torch.maximum(variance, floor))).reshape(self.count, self.n, self.n)

    # -------------------------------------------------------------------------------- report

    def result(self, nominal_l2: torch.Tensor, converged: bool, steps: int, seconds: float) -> PhaseRetrieval:
        r, jc, jn = self.jacobian()
        a, _ = self.normal_equations(r, jc, jn)
        dof = max(r.numel() - a.shape[0], 1)
        chi2 = float((r**2).sum()) / dof
        condition, _, _ = coefficient_conditioning(a, self.terms, len(self.free), self.count)
        warnings = []
        try:
            covariance = np.linalg.inv(schur_complement(a, self.terms, len(self.free), self.count)) * chi2
        except np.linalg.LinAlgError:
            covariance = np.full((self.terms, self.terms), np.inf)
        sigma = np.sqrt(np.maximum(np.diag(covariance), 0))
        with np.errstate(invalid="ignore", divide="ignore"):
            correlation = covariance / np.outer(sigma, sigma)
        if not converged:
            warnings.append(
                f"the fit did not converge in {steps} iterations: the coefficients are the last iterate's "
                "(more --max-iterations)"
            )
        coefficients = self.coefficients.numpy()
        delta = (self.coefficients @ self.basis).numpy()
        theta = self.lens.theta.numpy() + delta / 2
        term_records = [
            {
                "name": term_name(k),
                "n": 2 * (k + 1),
                "coefficient_rad": float(coefficients[k]),
                "sigma_rad": float(sigma[k]),
                "coefficient_waves": float(coefficients[k] / (2 * math.pi)),
                "sigma_waves": float(sigma[k] / (2 * math.pi)),
            }
            for k in range(self.terms)
        ]
        final_l2 = self.relative_l2()
        noise = torch.sqrt(torch.mean(1 / self.weights**2, dim=(-2, -1)))
        slots = self.slots.cpu()
        psfs = []
        for index in range(self.count):
            i, j = divmod(index, len(self.waves))
            depth = self.depths[i]
            psfs.append(
                {
                    "depth_m": None if math.isinf(depth) else depth,
                    "wavelength_m": self.waves[j],
                    "relative_l2_nominal": float(nominal_l2[index]),
                    "relative_l2": float(final_l2[index]),
                    "noise_sigma": float(noise[index]),
                    "noise_model": {
                        "read_variance": float(self.noise_model[index, 0]),
                        "shot_slope": float(self.noise_model[index, 1]),
                    },
                    "shift_px": [float(slots[index, 0]), float(slots[index, 1])],
                    "scale": float(self.s0[index] * (1 + slots[index, 2])),
                    "background": float(slots[index, 3] * self.bref[index]),
                }
            )
        return PhaseRetrieval(
            theta,
            delta,
            term_records,
            covariance,
            correlation,
            psfs,
            condition,
            chi2,
            steps,
            converged,
            seconds,
            self.nuisance,
            warnings,
        )


def schur_complement(a: np.ndarray, terms: int, per_psf: int, count: int) -> np.ndarray:
    """The coefficients' block of a normal matrix ``a`` (P × P, ordered [c_1..c_K, PSF 0's
    ``per_psf`` parameters, PSF 1's, ...], the PSFs' blocks independent of each other) with the
    per-PSF parameters eliminated (K × K): the information on the coefficients alone."""
    s = a[:terms, :terms].copy()
    for i in range(count):
        block = slice(terms + i * per_psf, terms + (i + 1) * per_psf)
        cross = a[:terms, block]
        s -= cross @ np.linalg.solve(a[block, block], cross.T)
    return s


def coefficient_conditioning(
    a: np.ndarray, terms: int, per_psf: int, count: int
) -> tuple[float, np.ndarray, np.ndarray]:
    """(condition number, eigenvalues ascending, eigenvectors) of :func:`schur_complement` scaled
    to unit diagonal by the coefficients' own sensitivities (the diagonal of ``a``): 1 for terms
    whose effects are independent, inf for a combination of terms that moves nothing."""
    s = schur_complement(a, terms, per_psf, count)
    diag = np.diag(a)[:terms]
    scale = 1 / np.sqrt(np.where(diag > 0, diag, np.inf))
    values, vectors = np.linalg.eigh(s * scale[:, None] * scale[None, :])
    top = values[-1] if values[-1] > 0 else 1.0
    low = values[0]
    return (math.inf if low <= top * 1e-300 else float(top / low)), values, vectors


def check_constrained(a: np.ndarray, terms: int, per_psf: int, count: int) -> float:
    """The condition number of the coefficients (:func:`coefficient_conditioning`), or an
    InputError naming --terms and the terms the normal matrix ``a`` leaves unconstrained: those
    that move no pixel, else those dominating the weakest direction when the condition number
    exceeds ``MAX_CONDITION``."""
    diag = np.diag(a)[:terms]
    largest = max(float(np.abs(a).max()), 1e-300)
    dead = [term_name(k) for k in range(terms) if diag[k] <= 1e-20 * largest]
    condition, _, vectors = coefficient_conditioning(a, terms, per_psf, count)
    if not dead and condition <= MAX_CONDITION:
        return condition
    if not dead:
        weakest = np.abs(vectors[:, 0])
        dead = [term_name(int(k)) for k in np.argsort(-weakest) if weakest[k] >= 0.3]
    raise InputError(
        "--terms",
        f"the cube does not constrain {', '.join(dead)} (condition number {condition:.3g} at the nominal, over "
        f"{MAX_CONDITION:.0g}): their effects on these PSFs cannot be told apart",
        "fewer --terms, or a cube with more depths or wavelengths (defocused planes on both sides of focus)",
    )


def _depth_text(depth: float) -> str:
    return "infinity" if math.isinf(depth) else format_length(float(depth))
