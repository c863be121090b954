"""`fignetctl render-views`: the bundled capture, a tabletop scene rendered with PyBullet."""

import click

from fignetctl.commands import options


@click.command("render-views")
@click.option(
    "-o", "--output", type=click.Path(file_okay=False), required=True, help="Capture folder to write."
)
@click.option(
    "--views",
    type=click.IntRange(min=2, max=10**4),
    default=40,
    show_default=True,
    help="Still views on the orbit.",
)
@click.option(
    "--width", type=click.IntRange(16, 4096), default=320, show_default=True, help="Image width, pixels."
)
@click.option(
    "--height", type=click.IntRange(16, 4096), default=240, show_default=True, help="Image height, pixels."
)
@click.option(
    "--objects",
    "num_objects",
    type=click.IntRange(2, 4),
    default=3,
    show_default=True,
    help="Everyday objects in the tray.",
)
@click.option(
    "--video-step",
    type=click.IntRange(min=1, max=10**4),
    default=3,
    show_default=True,
    help="Video frames per view interval (video frame k*step is view k).",
)
@options.seed_option
@click.option("--no-video", is_flag=True, help="Skip video.mp4.")
@options.overwrite_option
def render_views(output, views, width, height, num_objects, video_step, seed, no_video, overwrite):
    """Render the bundled capture: a textured tabletop scene with a tray and 2-4 objects,
    seen by an orbit of cameras (PyBullet TinyRenderer, offline).

    Writes images/, video.mp4, prompts.json and ground_truth/ (cameras.npz, depth, masks,
    meshes, scene.json) into the --output folder; see docs/render-views.md. Prints the folder
    on stdout.

    \b
    Example:
      fignetctl render-views -o capture --views 40 --width 320 --height 240 --seed 0
      fignetctl render-views -o tiny --views 8 --width 80 --height 60 --no-video
    """
    from fignetctl.core.synthetic_capture import render_capture

    path = options.output_path(output, overwrite)
    summary = render_capture(
        path,
        views=views,
        width=width,
        height=height,
        seed=seed,
        video=not no_video,
        overwrite=overwrite,
        num_objects=num_objects,
        video_step=video_step,
        progress=options.progress,
    )
    click.echo(
        f"rendered {summary['views']} views {width}x{height} of {', '.join(summary['objects'])} in "
        f"{summary['total_seconds']:.1f} s ({1000 * summary['seconds_per_view']:.0f} ms per view)",
        err=True,
    )
    click.echo(str(path))
