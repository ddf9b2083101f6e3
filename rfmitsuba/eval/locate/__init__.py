"""Device-free localisation: where a person stands, from the PAS they change, with a trained
two-stage model (a Stage-2 person field on its frozen Stage-1 background).

With the background and the person field fixed, the PAS the model renders at the query's antenna
positions is a function of the person's feet position ``p`` alone. :func:`locate` minimises a
loss between rendered and given PAS over ``p``:

1. **Where the person can be** (:class:`SearchRegion`): the box of the training walk grown by
   :data:`WALK_MARGIN_M` (``region="walk"``, the default: a person field is trained along the
   walk only, and far from it it may render a person who changes nothing, which an unlikely
   query then matches best), or the known room's whole free space (``region="room"``); in a
   known room, less what is within :data:`CLEARANCE_M` of the walls or of the footprint of
   furniture at body height (the walk of :func:`rfmitsuba.sim.person.walk` keeps 0.25 m). The
   height is the training walk's feet height (its median z), as in training.
2. **Coarse grid**: the loss at every free point of a grid of ``grid_m`` spacing; the ``starts``
   best points at least two grid steps apart start the descent.
3. **Descent**: for a person field whose channels are differentiable in the position
   (:meth:`rfmitsuba.models.coherent_gaussians_person.CoherentGaussianPersonField.channels_at`),
   Adam on ``(x, y)`` with Dr.Jit AD (``steps`` steps, step size ``lr_m`` decaying to a tenth);
   otherwise (the splat person field: its features enter its networks from the host) a bounded
   Nelder-Mead search of SciPy from each start (at most ``4 * steps`` losses each). A step that
   leaves the free space is not taken.
4. **Fringe hop and polish**: a coherent model's loss has a local minimum about every half
   wavelength (the person's scattered path changes phase as it moves), and a descent stops in
   the one nearest its start; a 5 x 5 grid of a quarter wavelength around each descent's end
   (:func:`_hop`) picks the best neighbouring one, and a third as many descent steps (a third
   of the step size) polish it. The estimate is the lowest loss met.

The loss is the training loss of :mod:`rfmitsuba.train.loss` (``0.8 L1 + 0.2 (1 - SSIM)`` on
min-max normalised PAS, ``loss="train"``) or ``1 - SSIM`` (``loss="ssim"``), on ``d x d``
block means of the PAS (``downsample``; 2 = 45 x 180, the coherent Gaussian field's training
images), averaged over the query's PAS. A query is one PAS or several of one person position
seen from several antenna positions (one frame of a dataset: every array position with the
person at one place).

What is compared with the query (:class:`Query`): the model's PAS with the person at ``p``
(``empty=None``, reference "none"), or, given the empty room's measured PAS at the same
positions, that measurement plus the model's change (its PAS with the person at ``p`` less its
background alone; reference "empty"). The second cancels the background's own error, which is
often larger than what the person changes and which the search otherwise spends the person
field on (:func:`evaluate_locate` uses it by default: a deployment that knows the room measures
it empty once).

Neither person field takes the person's heading (their inputs are the feet position and its
encoding), so nothing is assumed about it: the model renders the person it learned, over the
headings of the training walk.

:func:`evaluate_locate` scores the held-out walk positions of a run's dataset (its person test
split) for every Ours job of a comparison (one per seed), beside two floors that need no model:

* **fingerprint** - the person position of the training walk state whose measured PAS at the
  query's antenna positions are most similar (highest mean SSIM, Dr.Jit's float32 SSIM of
  :func:`rfmitsuba.train.loss.ssim`, skimage's definition, at 90 x 360);
* **centre** - the training walk's centroid (and, in a known room, the room's centre).

It also says where the model fails (:func:`failure_proxies`): error against the distance from
the array and from the transmitter, against whether the person blocks direct paths and whether
furniture hides them from the transmitter; and why (the model's loss at the true position against
its estimate's and against the background alone). :func:`plot_locate` draws true against estimated positions on the room's top
view; :func:`report_markdown` the tables.

One step per module: ``model`` (:class:`TwoStage`, a run's Ours jobs), ``region``
(:class:`SearchRegion`), ``query`` (:class:`Query`, the loss over person positions), ``search``
(the grid, descents, fringe hop: :func:`locate`, :func:`refine`), ``fingerprint_floor`` (:func:`fingerprint`),
``failures`` (:func:`failure_proxies`), ``evaluate`` (:func:`evaluate_locate` on the held-out
walk) and ``report`` (:func:`plot_locate`, :func:`report_markdown`). Every public name is
importable from the package.
"""
from .evaluate import evaluate_locate, query_antennas
from .failures import BODY_RADIUS_M, CHEST_M, failure_proxies
from .fingerprint_floor import fingerprint
from .model import TwoStage, job_folders, open_two_stage
from .query import LOSSES, REFERENCES, VIEWS_PER_CALL, Query, read_pas
from .region import BODY_HEIGHT_M, CLEARANCE_M, REGIONS, WALK_MARGIN_M, SearchRegion
from .report import MISS_CM, plot_locate, report_markdown
from .search import locate, refine, wavelength

__all__ = ["BODY_HEIGHT_M", "BODY_RADIUS_M", "CHEST_M", "CLEARANCE_M", "LOSSES", "MISS_CM", "REFERENCES", "REGIONS",
           "VIEWS_PER_CALL", "WALK_MARGIN_M", "Query", "SearchRegion", "TwoStage", "evaluate_locate",
           "failure_proxies", "fingerprint", "job_folders", "locate", "open_two_stage", "plot_locate",
           "query_antennas", "read_pas", "refine", "report_markdown", "wavelength"]
